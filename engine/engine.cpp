#include "engine/engine.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>

#include "engine/vk_result.h"
#include "engine/half.h"
#include "engine/kernel_tuner.h"

namespace spar {

namespace {

DeviceOptions deviceOptions(const EngineOptions& o) {
  o.tuning.validate();
  return {o.device, o.validation, o.verbose, o.limits};
}

}  // namespace

Engine::Engine(const EngineOptions& options)
    : options_(options),
      device_(std::make_unique<Device>(deviceOptions(options))),
      memory_(std::make_unique<MemoryAllocator>(*device_)),
      pipelines_(std::make_unique<PipelineCache>(*device_, options.pipelineCacheFile, options.logPipelines)) {
  memory_->failAllocation(options.faults.allocation);
  // The smaller of the option's limit and the device-limit profile's memory, named in errors.
  const uint64_t profileMemory = options.limits.deviceMemoryBytes.value_or(0);
  if (profileMemory && (!options.memoryLimitBytes || profileMemory < options.memoryLimitBytes))
    memory_->limit(profileMemory, "the memory of device-limit profile " + options.limits.name);
  else
    memory_->limit(options.memoryLimitBytes, "EngineOptions::memoryLimitBytes, SPAR_MEMORY_LIMIT_MB");
  plan_ = planKernels(device_->caps(), options_.tuning);
}

const Kernel& Engine::kernel(const KernelSpec& spec) {
  if (!plan_.storageInputs || std::find(spec.bindings.begin(), spec.bindings.end(), Bind::Texel) == spec.bindings.end())
    return pipelines_->get(spec);
  KernelSpec twin = spec;
  twin.shader += "_sx";
  for (Bind& b : twin.bindings)
    if (b == Bind::Texel) b = Bind::StorageInput;
  return pipelines_->get(twin);
}

void Engine::setTuning(const KernelTuning& tuning) {
  tuning.validate();
  KernelPlan plan = planKernels(device_->caps(), tuning);
  options_.tuning = tuning;
  plan_ = std::move(plan);
}

const KernelPlan& Engine::plan() {
  if (plan_.measureTiles && !planning_) {
    // Measured once, whether or not it succeeds; meanwhile the tuner's own GEMMs see the plan
    // as it stands.
    plan_.measureTiles = false;
    planning_ = true;
    struct Done {
      bool& flag;
      ~Done() { flag = false; }
    } done{planning_};
    measureKernelChoice(*this, plan_);
  }
  return plan_;
}

void Engine::waitForSubmission(VkFence fence, const std::function<std::string()>& what) {
  const unsigned long long ms = options_.submitTimeoutMs;
  const bool injected = ++submissions_ == options_.faults.submission;
  // An injected timeout lets the work finish first, so that what follows the error (freeing
  // the submission's resources) is as valid as after a real submission.
  const uint64_t ns = ms && !injected && ms < UINT64_MAX / 1000000 ? ms * 1000000 : UINT64_MAX;
  const VkResult r = vkWaitForFences(device_->handle(), 1, &fence, VK_TRUE, ns);
  if (r == VK_TIMEOUT || injected) {
    char limit[32];
    std::snprintf(limit, sizeof(limit), "%g s", double(ms) / 1000.0);
    throw Error("the device did not finish " + what() + " within " + limit +
                " (hung, lost or too slow; SPAR_SUBMIT_TIMEOUT_MS sets the limit)" +
                (injected ? " (injected: submission " + std::to_string(submissions_) + ")" : ""));
  }
  if (r != VK_SUCCESS) vkCheck(r, what().c_str());
}

Engine::~Engine() {
  pipelines_.reset();
  memory_.reset();
  device_.reset();
}

Tensor Engine::tensor(const Shape& shape, DType dtype) {
  VkDeviceSize bytes = tensorBytes(shape, dtype);
  // Rounded up to 16 bytes so every tensor can be read through 4-component texel views, plus
  // kTexelViewSlack bytes a texel view may reach past the tensor, and never a power of two:
  // a CPU driver keys compiled variants on both (engine/recorder.cpp, stableTexelRange), so
  // every buffer looks the same to it and each pipeline is compiled once.
  VkDeviceSize padded = (bytes + 15) / 16 * 16 + kTexelViewSlack;
  if (!(padded & (padded - 1))) padded += 16;
  auto buffer = std::make_shared<Buffer>(*device_, *memory_, padded, MemoryUsage::Tensor);
  return Tensor(std::move(buffer), 0, shape, dtype);
}

void Engine::stagedCopy(const Tensor& t, void* data, size_t bytes, bool toDevice) {
  Buffer staging(*device_, *memory_, bytes, MemoryUsage::Staging);
  if (toDevice) std::memcpy(staging.mapped(), data, bytes);
  VkDevice dev = device_->handle();
  VkCommandPoolCreateInfo poolInfo{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
  poolInfo.flags = VK_COMMAND_POOL_CREATE_TRANSIENT_BIT;
  poolInfo.queueFamilyIndex = device_->queueFamily();
  VkCommandPool pool;
  SPAR_VK(vkCreateCommandPool(dev, &poolInfo, nullptr, &pool));
  VkCommandBufferAllocateInfo alloc{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
  alloc.commandPool = pool;
  alloc.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  alloc.commandBufferCount = 1;
  VkCommandBuffer cmd;
  SPAR_VK(vkAllocateCommandBuffers(dev, &alloc, &cmd));
  VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  vkBeginCommandBuffer(cmd, &begin);
  VkBufferCopy region{};
  region.size = bytes;
  if (toDevice) {
    region.dstOffset = t.byteOffset();
    vkCmdCopyBuffer(cmd, staging.handle(), t.buffer().handle(), 1, &region);
  } else {
    region.srcOffset = t.byteOffset();
    vkCmdCopyBuffer(cmd, t.buffer().handle(), staging.handle(), 1, &region);
  }
  VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER};
  barrier.srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
  barrier.dstAccessMask = VK_ACCESS_HOST_READ_BIT | VK_ACCESS_SHADER_READ_BIT;
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_HOST_BIT | VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                       0, 1, &barrier, 0, nullptr, 0, nullptr);
  vkEndCommandBuffer(cmd);
  VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
  submit.commandBufferCount = 1;
  submit.pCommandBuffers = &cmd;
  VkFenceCreateInfo fenceInfo{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
  VkFence fence;
  SPAR_VK(vkCreateFence(dev, &fenceInfo, nullptr, &fence));
  try {
    vkCheck(vkQueueSubmit(device_->queue(), 1, &submit, fence), "staged copy");
    waitForSubmission(fence, [] { return std::string("a staged copy"); });
  } catch (...) {
    vkDestroyFence(dev, fence, nullptr);
    vkDestroyCommandPool(dev, pool, nullptr);
    throw;
  }
  vkDestroyFence(dev, fence, nullptr);
  vkDestroyCommandPool(dev, pool, nullptr);
  if (!toDevice) std::memcpy(data, staging.mapped(), bytes);
}

void Engine::write(const Tensor& t, const void* data, size_t bytes) {
  if (bytes != t.bytes()) throw Error("writing " + std::to_string(bytes) + " bytes into " + t.describe());
  if (bytes == 0) return;  // an empty tensor (its data pointer may be null: memcpy must not see it)
  if (void* p = t.buffer().mapped()) {
    std::memcpy(static_cast<char*>(p) + t.byteOffset(), data, bytes);
  } else {
    stagedCopy(t, const_cast<void*>(data), bytes, true);
  }
}

void Engine::read(const Tensor& t, void* data, size_t bytes) {
  if (bytes != t.bytes()) throw Error("reading " + std::to_string(bytes) + " bytes from " + t.describe());
  if (bytes == 0) return;
  if (void* p = t.buffer().mapped()) {
    std::memcpy(data, static_cast<char*>(p) + t.byteOffset(), bytes);
  } else {
    stagedCopy(t, data, bytes, false);
  }
}

void Engine::upload(const Tensor& t, std::span<const float> values) {
  if (static_cast<int64_t>(values.size()) != t.numel())
    throw Error("uploading " + std::to_string(values.size()) + " values into " + t.describe());
  if (t.dtype() == DType::F32) return write(t, values.data(), values.size_bytes());
  if (t.dtype() != DType::F16) throw Error("upload of floats into " + t.describe());
  std::vector<uint16_t> half(values.size());
  // Saturate like the kernels' fp16 stores: a weight beyond 65504 stays finite.
  for (size_t i = 0; i < values.size(); ++i)
    half[i] = floatToHalf(std::isnan(values[i]) ? values[i] : std::clamp(values[i], -65504.0f, 65504.0f));
  write(t, half.data(), half.size() * 2);
}

std::vector<float> Engine::download(const Tensor& t) {
  std::vector<float> out(static_cast<size_t>(t.numel()));
  if (t.dtype() == DType::F32) {
    read(t, out.data(), out.size() * 4);
  } else if (t.dtype() == DType::F16) {
    std::vector<uint16_t> half(out.size());
    read(t, half.data(), half.size() * 2);
    for (size_t i = 0; i < out.size(); ++i) out[i] = halfToFloat(half[i]);
  } else {
    std::vector<int32_t> ints(out.size());
    read(t, ints.data(), ints.size() * 4);
    for (size_t i = 0; i < out.size(); ++i) out[i] = static_cast<float>(ints[i]);
  }
  return out;
}

Tensor Engine::fromFloats(const Shape& shape, std::span<const float> values, DType dtype) {
  Tensor t = tensor(shape, dtype);
  upload(t, values);
  return t;
}

}  // namespace spar
