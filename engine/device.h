// The Vulkan instance, the chosen physical device, its queue and what it can do.
#pragma once
#include <vulkan/vulkan.h>

#include <cstdint>
#include <mutex>
#include <string>
#include <vector>

#include "spar/device_limits.h"

namespace spar {

struct DeviceOptions {
  // Which device: an index from listDevices() or a case-insensitive part of its name; a name
  // of a driver installed outside the loader's paths (SwiftShader: engine/extra_drivers.h)
  // brings that driver in.
  // Empty: the first discrete, integrated, virtual, then CPU device (EngineOptions::
  // fromEnvironment reads SPAR_DEVICE into it).
  std::string select;
  // Enable VK_LAYER_KHRONOS_validation and count its messages (tests always do).
  bool validation = false;
  // Print the chosen device and the features used to stderr.
  bool verbose = false;
  // Act as if the device had at most these limits and features (EngineOptions::limits).
  DeviceLimits limits;
};

// One matrix multiply-add a subgroup can do on VK_KHR_cooperative_matrix: an M x K matrix A
// times a K x N matrix B plus an M x N matrix C (component types as the extension numbers
// them: 0 fp16, 1 fp32; only subgroup-scope entries are kept).
struct CoopMatSize {
  uint32_t m = 0, n = 0, k = 0;
  int aType = -1, bType = -1, cType = -1, resultType = -1;
};

// What the engine reads off the device to choose kernels, tile sizes and binding ranges.
struct DeviceCaps {
  std::string name;
  VkPhysicalDeviceType type = VK_PHYSICAL_DEVICE_TYPE_OTHER;
  VkDriverId driverId = static_cast<VkDriverId>(0);
  std::string driverInfo;      // e.g. "Mesa 22.3.6 (LLVM 15.0.6)"
  uint32_t driverVersion = 0;  // vendor-encoded (lavapipe reports 1: its version is in driverInfo)
  uint32_t mesaMajor = 0;      // Mesa drivers: the major version from driverInfo (22, 25, ...); else 0
  uint32_t apiVersion = 0;
  uint32_t vendorId = 0, deviceId = 0;
  uint32_t subgroupSize = 1;
  bool subgroupArithmetic = false;   // subgroupAdd / subgroupMax in compute shaders
  bool subgroupShuffle = false;      // subgroupShuffle in compute shaders
  // VK_EXT_subgroup_size_control, enabled: pipelines can require full subgroups (and, where
  // requiredSubgroupSizeStages has compute, a size between min and max).
  bool fullSubgroups = false;
  uint32_t minSubgroupSize = 0, maxSubgroupSize = 0;
  bool requiredSubgroupSize = false;
  bool cooperativeMatrix = false;    // VK_KHR_cooperative_matrix, enabled (needs fullSubgroups)
  std::vector<CoopMatSize> coopMatSizes;
  uint64_t maxStorageBufferRange = 0;
  uint64_t maxTexelBufferElements = 0;
  uint64_t minStorageBufferOffsetAlignment = 1;
  uint64_t minTexelBufferOffsetAlignment = 1;
  uint64_t maxMemoryAllocationSize = 0;
  uint32_t maxPushConstantsSize = 0;
  uint32_t maxWorkGroupCount[3] = {0, 0, 0};
  uint32_t maxWorkGroupInvocations = 0;
  uint32_t maxSharedMemory = 0;
  uint32_t maxPerStageStorageBuffers = 0;  // storage-buffer bindings one kernel may have
  uint32_t maxPerStageSampledImages = 0;   // texel-buffer bindings one kernel may have
  std::string limitsProfile;               // the device-limit profile applied ("" for none)
  float timestampPeriodNs = 0;
  bool timestamps = false;
  bool shaderFloat16 = false;
  bool storageBuffer16BitAccess = false;
  bool fp16TexelBuffers = false;     // R16G16B16A16_SFLOAT / R16_SFLOAT as uniform texel buffers
  bool hostVisibleDeviceLocal = false;  // a memory type both device-local and mappable
  bool isCpu() const { return type == VK_PHYSICAL_DEVICE_TYPE_CPU; }
  bool isLlvmpipe() const { return driverId == VK_DRIVER_ID_MESA_LLVMPIPE; }
  // llvmpipe before Mesa 26 keys its on-disk shader cache without LP_NATIVE_VECTOR_WIDTH: a run at
  // another width reuses the machine code built at the first (right results, the other width's
  // speed). Measured: 22.3 and 25.0.7 reuse it, 26.1 builds anew (docs/first-run-and-kernels.md).
  bool shaderCacheIgnoresVectorWidth() const { return isLlvmpipe() && mesaMajor > 0 && mesaMajor < 26; }
  bool supportsFp16Storage() const { return storageBuffer16BitAccess && fp16TexelBuffers; }
};

class Device {
 public:
  explicit Device(const DeviceOptions& options = {});
  ~Device();
  Device(const Device&) = delete;
  Device& operator=(const Device&) = delete;

  // "index: name (type)" for every Vulkan device on this machine; with `extraDrivers`, those of
  // the drivers installed outside the loader's paths too (their indices count only in such a
  // list: select them by name).
  static std::vector<std::string> listDevices(bool extraDrivers = false);
  // The devices' names, each once (identical devices share one), for DeviceOptions::select.
  static std::vector<std::string> deviceNames(bool extraDrivers = false);

  VkInstance instance() const { return instance_; }
  VkPhysicalDevice physical() const { return physical_; }
  VkDevice handle() const { return device_; }
  VkQueue queue() const { return queue_; }
  uint32_t queueFamily() const { return queueFamily_; }
  const DeviceCaps& caps() const { return caps_; }
  const VkPhysicalDeviceMemoryProperties& memoryProperties() const { return memory_; }

  // Largest range one storage-buffer binding may cover. Tests lower it to exercise the
  // split paths that tensors above 128 MiB take on lavapipe without allocating that much.
  uint64_t bindingRangeLimit() const { return bindingRangeLimit_; }
  void setBindingRangeLimitForTesting(uint64_t bytes) { bindingRangeLimit_ = bytes; }

  // Validation-layer messages of severity warning or error seen so far.
  size_t validationMessageCount() const;
  std::vector<std::string> validationMessages() const;
  void recordValidationMessage(const std::string& message);
  bool validationEnabled() const { return messenger_ != VK_NULL_HANDLE; }

 private:
  void createInstance(bool validation, const std::string& select);
  void pickPhysicalDevice(const std::string& select);
  void readCaps();
  void createLogicalDevice();

  VkInstance instance_ = VK_NULL_HANDLE;
  VkDebugUtilsMessengerEXT messenger_ = VK_NULL_HANDLE;
  VkPhysicalDevice physical_ = VK_NULL_HANDLE;
  VkDevice device_ = VK_NULL_HANDLE;
  VkQueue queue_ = VK_NULL_HANDLE;
  uint32_t queueFamily_ = 0;
  DeviceCaps caps_;
  VkPhysicalDeviceMemoryProperties memory_{};
  uint64_t bindingRangeLimit_ = 0;
  mutable std::mutex messagesMutex_;
  std::vector<std::string> messages_;
};

}  // namespace spar
