// The engine a model runs on: device, memory, pipelines, and tensor upload/download.
#pragma once
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "engine/device.h"
#include "engine/kernel_plan.h"
#include "engine/memory.h"
#include "engine/pipeline.h"
#include "engine/tensor.h"
#include "spar/engine_options.h"

namespace spar {

// Bytes every tensor's buffer holds beyond the tensor (see Engine::tensor).
constexpr VkDeviceSize kTexelViewSlack = 256;


class Engine {
 public:
  explicit Engine(const EngineOptions& options = {});
  ~Engine();
  Engine(const Engine&) = delete;
  Engine& operator=(const Engine&) = delete;

  const EngineOptions& options() const { return options_; }
  // Replaces the tile overrides between batches (tests run one device's kernel shapes on
  // another; kernels are keyed by their shapes, so nothing made earlier goes stale).
  void setTuning(const KernelTuning& tuning);
  // Which kernel family and tiles each op uses here (engine/kernel_plan.h). The first call on
  // a GPU may measure the GEMM tile candidates (engine/kernel_tuner.h) or read the earlier
  // measurement from kernel-choice.json beside the pipeline cache file.
  const KernelPlan& plan();
  Device& device() { return *device_; }
  const DeviceCaps& caps() const { return device_->caps(); }
  MemoryAllocator& memory() { return *memory_; }
  PipelineCache& pipelines() { return *pipelines_; }
  // The kernel for a spec; on a device whose texel buffers are too short (plan().storageInputs)
  // the storage-input twin of a kernel with texel bindings (shaders/common.glsl, TEXEL_INPUT).
  const Kernel& kernel(const KernelSpec& spec);
  // Whether kernels can read fp16 inputs (fp16 weights) here: always through storage inputs
  // (halves unpacked from 32-bit words), through texel buffers where the device has fp16
  // storage and fp16 texel formats. Writing fp16 needs caps().storageBuffer16BitAccess.
  bool readsFp16Inputs() { return plan().storageInputs || caps().supportsFp16Storage(); }

  // A new tensor with its own buffer; contents undefined.
  Tensor tensor(const Shape& shape, DType dtype = DType::F32);

  // Raw bytes to and from a tensor (size must equal tensor.bytes()).
  void write(const Tensor& t, const void* data, size_t bytes);
  void read(const Tensor& t, void* data, size_t bytes);
  // Floats converted to and from the tensor's dtype (f32 or f16; fp16 saturates at +-65504).
  void upload(const Tensor& t, std::span<const float> values);
  std::vector<float> download(const Tensor& t);
  Tensor fromFloats(const Shape& shape, std::span<const float> values, DType dtype = DType::F32);

  // Waits for a submitted fence at most EngineOptions::submitTimeoutMs; throws Error naming
  // what was submitted on a timeout (or the injected one, EngineOptions::faults.submission).
  // `what` is called only then: every run() waits here, and the common case builds no text.
  void waitForSubmission(VkFence fence, const std::function<std::string()>& what);
  unsigned long long submissions() const { return submissions_; }

 private:
  void stagedCopy(const Tensor& t, void* data, size_t bytes, bool toDevice);

  EngineOptions options_;
  std::unique_ptr<Device> device_;
  std::unique_ptr<MemoryAllocator> memory_;
  std::unique_ptr<PipelineCache> pipelines_;
  unsigned long long submissions_ = 0;
  KernelPlan plan_;
  bool planning_ = false;  // measuring: the tuner's own GEMMs use the plan as it stands
};

}  // namespace spar
