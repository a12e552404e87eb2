// Compute pipelines built from embedded SPIR-V. A Kernel is a shader variant with its
// specialization constants and binding layout; the driver pipelines made from it are kept
// here, one per texel signature (the formats of its texel bindings), for the life of the
// engine, together with what the process measured about each (engine/pipeline_stats.h).
//
// Why one pipeline per texel signature: a CPU driver (llvmpipe) compiles a machine-code variant
// of a pipeline for each texel format it sees bound, and only the first variant of a pipeline
// gets a stable key in Mesa's disk cache (later ones hash an IR the first compile rewrote).
// One signature per pipeline makes every pipeline compile once per driver cache.
#pragma once
#include <vulkan/vulkan.h>

#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "engine/device.h"
#include "engine/pipeline_stats.h"

namespace spar {

// How a kernel sees each binding, in binding order (0, 1, 2, ...).
enum class Bind : uint8_t {
  Read,       // readonly storage buffer
  Write,      // writeonly storage buffer
  ReadWrite,  // storage buffer read and written (in-place ops)
  Texel,      // uniform texel buffer (samplerBuffer): llvmpipe gathers these ~2x faster than SSBO loads
  // A texel input of a storage-input twin (*_sx, Engine::kernel): a readonly storage buffer of
  // 32-bit words that the shader decodes as fp32 or fp16 (shaders/common.glsl, TEXEL_INPUT).
  StorageInput,
};

// Specialization constant of the *_sx twins: bit b set = binding b holds fp16 (its words are
// pairs of halves). Set per pipeline from the formats bound (PipelineCache::build).
constexpr uint32_t kStorageInputF16ConstantId = 63;

struct KernelSpec {
  std::string shader;            // variant name from a "//! variant" line
  std::vector<Bind> bindings;
  uint32_t pushBytes = 0;
  // Specialization constants by constant_id 0, 1, 2, ...; ids 0-2 are the workgroup size
  // (local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in every shader.
  std::vector<int32_t> constants;
  // Non-zero: the kernel divides its workgroup among subgroups of this size (constant 0, the
  // workgroup's x size, is a multiple of it): the pipeline requires full subgroups, and this
  // size where the device lets a pipeline choose (DeviceCaps::requiredSubgroupSize).
  uint32_t subgroupSize = 0;
  // Write the constants' values into the module instead of specializing it (engine/spirv_freeze.h):
  // set by ops whose family the plan says needs it (KernelPlan::freezeConstants).
  bool freezeConstants = false;
};

struct Kernel {
  std::string name;  // shader name plus constants, for profiles and errors
  KernelSpec spec;
  std::vector<Bind> bindings;
  uint32_t pushBytes = 0;
  uint32_t localSize[3] = {1, 1, 1};
  // The storage-input twin of a texel kernel (shader "<variant>_sx"): what ops pass as texel
  // arguments is bound as storage buffers of words, fp32 or fp16 (Bind::StorageInput; Engine::kernel
  // chooses it, engine/kernel_plan.h).
  bool storageInputs = false;
  VkDescriptorSetLayout setLayout = VK_NULL_HANDLE;
  VkPipelineLayout layout = VK_NULL_HANDLE;
};

// One driver pipeline: a kernel for one texel signature.
struct Pipeline {
  const Kernel* kernel = nullptr;
  // e.g. "f32x4,f16x4,f32x1": the formats of the texel (or storage-input) bindings in binding
  // order; "" for kernels without them
  std::string signature;
  std::string name;       // kernel name, plus the signature when a texel binding is not f32
  VkPipeline handle = VK_NULL_HANDLE;
  PipelineStats stats;
};

class PipelineCache {
 public:
  // cacheFile: where the driver's pipeline cache is kept across runs ("" for none); it
  // saves the compile of every kernel at start-up on drivers that honour it (GPU drivers;
  // lavapipe 22.3 stores nothing there and relies on Mesa's shader disk cache instead).
  // log: every pipeline's creation on stderr (EngineOptions::logPipelines).
  PipelineCache(Device& device, std::string cacheFile = "", bool log = false);
  ~PipelineCache();
  PipelineCache(const PipelineCache&) = delete;
  PipelineCache& operator=(const PipelineCache&) = delete;

  // The kernel for a spec: layouts only; no driver pipeline is made until a dispatch needs one.
  const Kernel& get(const KernelSpec& spec);
  size_t size() const { return kernels_.size(); }

  // The pipeline of a kernel for a texel signature, created on first request.
  Pipeline& pipeline(const Kernel& kernel, const std::string& signature);
  // Creates every missing pipeline of the list at once, on several threads where the device
  // has more than one core to give (vkCreateComputePipelines is where GPU drivers compile).
  void create(const std::vector<std::pair<const Kernel*, std::string>>& wanted);

  // Every pipeline made so far, in creation order.
  std::vector<const Pipeline*> pipelines() const;
  PipelineTotals totals() const;

 private:
  VkPipeline build(const Kernel& kernel, const std::string& signature, double* ms);
  Pipeline* find(const Kernel& kernel, const std::string& signature);

  Device& device_;
  std::string cacheFile_;
  bool log_ = false;
  VkPipelineCache driverCache_ = VK_NULL_HANDLE;
  std::map<std::string, std::unique_ptr<Kernel>> kernels_;
  std::map<std::pair<const Kernel*, std::string>, std::unique_ptr<Pipeline>> pipelines_;
  std::vector<const Pipeline*> order_;
};

}  // namespace spar
