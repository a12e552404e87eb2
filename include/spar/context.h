// The engine a model runs on: one Vulkan device with its memory and compiled kernels. Create
// one per device and keep it: kernels compiled for one request are reused by the next.
#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "spar/engine_options.h"
#include "spar/export.h"
#include "spar/kernel_report.h"
#include "spar/memory.h"

namespace spar {

// The device as the engine uses it: after any device-limit profile (EngineOptions::limits).
struct DeviceInfo {
  std::string name;            // e.g. "llvmpipe (LLVM 15.0.6, 256 bits)"
  std::string driver;          // e.g. "Mesa 22.3.6 (LLVM 15.0.6)"
  uint32_t vulkanMajor = 0, vulkanMinor = 0;
  std::string limitsProfile;   // the profile's name, "" for none
  uint64_t maxTexelBufferElements = 0;
  uint64_t maxStorageBufferRange = 0;
  uint32_t maxComputeSharedMemorySize = 0;
  uint32_t maxComputeWorkGroupInvocations = 0;
  uint32_t maxPushConstantsSize = 0;
  uint32_t maxPerStageStorageBuffers = 0;
  uint32_t maxPerStageTexelBuffers = 0;
  uint64_t minStorageBufferOffsetAlignment = 0;
  uint64_t minTexelBufferOffsetAlignment = 0;
  bool shaderFloat16 = false;   // fp16 arithmetic
  bool fp16Storage = false;     // 16-bit storage and fp16 texel buffers (Precision::FP16 needs it)
  uint32_t subgroupSize = 0;
  bool subgroupArithmetic = false;
  bool cooperativeMatrix = false;
  bool hostVisibleDeviceLocal = false;  // uploads map device memory directly (no staging copies)
};

class SPAR_API Context {
 public:
  // Throws spar::Error when no Vulkan 1.2 device matches (the message lists what was found).
  explicit Context(const EngineOptions& options = EngineOptions::fromEnvironment());
  ~Context();
  Context(const Context&) = delete;
  Context& operator=(const Context&) = delete;

  // "index: name (type)" of every Vulkan device on this machine.
  static std::vector<std::string> listDevices();
  // Every device's name once, for EngineOptions::device; with `extraDrivers` also those of
  // drivers installed outside the loader's paths (SwiftShader in a browser package).
  static std::vector<std::string> deviceNames(bool extraDrivers = false);

  std::string deviceName() const;
  DeviceInfo device() const;
  const EngineOptions& options() const;
  // Messages the validation layer reported so far (EngineOptions::validation; else 0).
  uint64_t validationMessages() const;
  // The kernel family per op on this device and why, one line each. On a GPU the first call
  // measures the tile candidates (EngineOptions' KernelTuning::measureKernels).
  std::vector<std::string> kernelPlan();
  // Every kernel made so far, with the plan (spar/kernel_report.h).
  KernelReport kernelReport();
  MemoryStats memory() const;

  struct Impl;
  Impl& impl() { return *impl_; }

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace spar
