// Compute pipelines built lazily from embedded SPIR-V, once per (shader variant, binding
// layout, specialization constants), and kept for the life of the engine.
#pragma once
#include <vulkan/vulkan.h>

#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "engine/device.h"

namespace spar {

// How a kernel sees each binding, in binding order (0, 1, 2, ...).
enum class Bind : uint8_t {
  Read,       // readonly storage buffer
  Write,      // writeonly storage buffer
  ReadWrite,  // storage buffer read and written (in-place ops)
  Texel,      // uniform texel buffer (samplerBuffer): llvmpipe gathers these ~2x faster than SSBO loads
};

struct KernelSpec {
  std::string shader;            // variant name from a "//! variant" line
  std::vector<Bind> bindings;
  uint32_t pushBytes = 0;
  // Specialization constants by constant_id 0, 1, 2, ...; ids 0-2 are the workgroup size
  // (local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in every shader.
  std::vector<int32_t> constants;
};

struct Kernel {
  std::string name;  // shader name plus constants, for profiles and errors
  std::vector<Bind> bindings;
  uint32_t pushBytes = 0;
  uint32_t localSize[3] = {1, 1, 1};
  VkDescriptorSetLayout setLayout = VK_NULL_HANDLE;
  VkPipelineLayout layout = VK_NULL_HANDLE;
  VkPipeline pipeline = VK_NULL_HANDLE;
};

class PipelineCache {
 public:
  // cacheFile: where the driver's pipeline cache is kept across runs ("" for none); it
  // saves the JIT of every kernel at start-up on drivers that honour it.
  PipelineCache(Device& device, std::string cacheFile = "");
  ~PipelineCache();
  PipelineCache(const PipelineCache&) = delete;
  PipelineCache& operator=(const PipelineCache&) = delete;

  const Kernel& get(const KernelSpec& spec);
  size_t size() const { return kernels_.size(); }

 private:
  Device& device_;
  std::string cacheFile_;
  VkPipelineCache driverCache_ = VK_NULL_HANDLE;
  std::map<std::string, std::unique_ptr<Kernel>> kernels_;
};

}  // namespace spar
