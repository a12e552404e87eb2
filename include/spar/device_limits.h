// Device-limit profiles: the engine acts as if the Vulkan device had at most these limits and
// features (EngineOptions::limits, SPAR_DEVICE_LIMITS=NAME or a JSON file of the same fields).
// The kernel plan, every op's binding splits and the memory budget follow them, so a run on a
// generous device (lavapipe) exercises what a phone or a board would need. A profile can only
// tighten: the real device's limits stay the ceiling. Named profiles and their sources:
// docs in docs/portability.md ("Device-limit profiles"); engine/device_limits.cpp holds the values.
#pragma once
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "spar/export.h"

namespace spar {

struct SPAR_API DeviceLimits {
  std::string name;  // the profile's name ("" when none is set); a file's path for JSON ones

  // VkPhysicalDeviceLimits (and maintenance3) fields, by their Vulkan names. Unset: the device's.
  std::optional<uint64_t> maxTexelBufferElements;
  std::optional<uint64_t> maxStorageBufferRange;
  std::optional<uint64_t> maxMemoryAllocationSize;
  std::optional<uint32_t> maxComputeSharedMemorySize;
  std::optional<uint32_t> maxComputeWorkGroupInvocations;
  std::optional<uint32_t> maxComputeWorkGroupCount;  // each of x, y, z
  std::optional<uint32_t> maxPushConstantsSize;
  std::optional<uint32_t> maxPerStageDescriptorStorageBuffers;
  std::optional<uint32_t> maxPerStageDescriptorSampledImages;  // uniform texel buffers count here
  // Alignments tighten upwards: a binding must start at a multiple of the larger of the two.
  std::optional<uint32_t> minStorageBufferOffsetAlignment;
  std::optional<uint32_t> minTexelBufferOffsetAlignment;
  // Features: false turns one off (true cannot turn on what the device lacks).
  std::optional<bool> shaderFloat16;            // fp16 arithmetic
  std::optional<bool> storageBuffer16BitAccess; // fp16 storage (and fp16 texel buffers with it)
  std::optional<bool> subgroupArithmetic;       // subgroupAdd / subgroupMax in compute
  std::optional<bool> cooperativeMatrix;        // VK_KHR_cooperative_matrix
  std::optional<bool> subgroupSizeControl;      // VK_EXT_subgroup_size_control (full subgroups)
  // Device memory a run may use at most, in bytes (the memory budget: requests that cannot fit
  // are refused before work, naming this profile).
  std::optional<uint64_t> deviceMemoryBytes;

  bool empty() const;
  // One line: the name and every field set, e.g. "vulkan-1.2-min: texel 65536, storage 128 MiB, ...".
  std::string describe() const;

  // The named profiles (vulkan-1.2-min, android-baseline-2022, raspberry-pi-5, mali-g610,
  // adreno-610), in that order.
  static std::vector<std::string> profileNames();
  // A named profile; throws Error listing the names for an unknown one.
  static DeviceLimits profile(const std::string& name);
  // A JSON object of the fields above (any subset; "name" optional); throws Error (one line,
  // naming the file and the field) for an unknown field or a value of the wrong type.
  static DeviceLimits fromJsonFile(const std::string& path);
  // A profile's name, else a JSON file's path (what SPAR_DEVICE_LIMITS holds).
  static DeviceLimits parse(const std::string& nameOrPath);
};

}  // namespace spar
