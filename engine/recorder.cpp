#include "engine/recorder.h"

#include <algorithm>
#include <cstdio>
#include <cstring>

#include "engine/engine.h"
#include "engine/vk_result.h"

namespace spar {
namespace {

constexpr uint32_t kQueriesPerPool = 1024;
constexpr uint32_t kSetsPerPool = 512;

VkFormat texelFormat(DType dtype, int components) {
  if (isQuantized(dtype)) return VK_FORMAT_R32_UINT;  // the words of codes and scales (shaders/quant.glsl)
  if (dtype == DType::F32) return components == 4 ? VK_FORMAT_R32G32B32A32_SFLOAT : VK_FORMAT_R32_SFLOAT;
  if (dtype == DType::F16) return components == 4 ? VK_FORMAT_R16G16B16A16_SFLOAT : VK_FORMAT_R16_SFLOAT;
  return components == 4 ? VK_FORMAT_R32G32B32A32_SINT : VK_FORMAT_R32_SINT;
}

bool powerOfTwo(VkDeviceSize v) { return v && !(v & (v - 1)); }

// llvmpipe (Mesa 22.3) compiles a new machine-code variant of a pipeline whenever the
// static state of a bound texel buffer changes, and that state holds two size bits: whether
// the VkBuffer's size is a power of two, and (read through a union) whether bits 8-15 of the
// view's byte range are all zero. Engine::tensor makes no buffer size a power of two and
// leaves kTexelViewSlack bytes after every tensor; here a range whose bits 8-15 are zero is
// extended by 256 bytes into that slack. Every dispatch of a pipeline then shows the driver
// the same state and the pipeline is compiled once. Kernels never read past their tensor,
// so the longer view changes nothing they read, on any device.
VkDeviceSize stableTexelRange(VkDeviceSize offset, VkDeviceSize range, VkDeviceSize bufferSize,
                              VkDeviceSize texelBytes, uint64_t maxTexels) {
  if ((range >> 8) & 0xff) return range;
  const VkDeviceSize longer = range + 256;
  if (offset + longer > bufferSize || longer / texelBytes > maxTexels) return range;
  return longer;
}

// What a driver may key compiled variants on beyond the formats (in the signature): the two
// size bits above, per texel binding ("p"/"-": power-of-two buffer; "z"/"-": zero bits 8-15).
std::string texelStateOf(VkDeviceSize bufferSize, VkDeviceSize range) {
  std::string s;
  s += powerOfTwo(bufferSize) ? 'p' : '-';
  s += ((range >> 8) & 0xff) ? '-' : 'z';
  return s;
}

std::string texelTypeName(DType dtype, int components) {
  return std::string(dtype == DType::F32 ? "f32" : dtype == DType::F16 ? "f16" : isQuantized(dtype) ? "u32" : "i32") +
         "x" + std::to_string(components);
}

std::string hexOf(const std::vector<uint8_t>& bytes) {
  static const char* digits = "0123456789abcdef";
  std::string s;
  for (uint8_t b : bytes) {
    s += digits[b >> 4];
    s += digits[b & 15];
  }
  return s;
}

}  // namespace

Recorder::Recorder(Engine& engine, bool profile) : engine_(engine), profile_(profile && engine.device().caps().timestamps) {
  VkDevice dev = engine_.device().handle();
  VkCommandPoolCreateInfo poolInfo{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
  poolInfo.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
  poolInfo.queueFamilyIndex = engine_.device().queueFamily();
  SPAR_VK(vkCreateCommandPool(dev, &poolInfo, nullptr, &pool_));
  VkCommandBufferAllocateInfo alloc{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
  alloc.commandPool = pool_;
  alloc.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  alloc.commandBufferCount = 1;
  SPAR_VK(vkAllocateCommandBuffers(dev, &alloc, &cmd_));
  VkFenceCreateInfo fenceInfo{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
  SPAR_VK(vkCreateFence(dev, &fenceInfo, nullptr, &fence_));
}

Recorder::~Recorder() {
  VkDevice dev = engine_.device().handle();
  releaseTransient();
  for (auto p : descriptorPools_) vkDestroyDescriptorPool(dev, p, nullptr);
  for (auto q : queryPools_) vkDestroyQueryPool(dev, q, nullptr);
  vkDestroyFence(dev, fence_, nullptr);
  vkDestroyCommandPool(dev, pool_, nullptr);
}

void Recorder::writeTimestamp() {
  uint32_t pool = queriesUsed_ / kQueriesPerPool, index = queriesUsed_ % kQueriesPerPool;
  VkDevice dev = engine_.device().handle();
  if (pool == queryPools_.size()) {
    VkQueryPoolCreateInfo info{VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO};
    info.queryType = VK_QUERY_TYPE_TIMESTAMP;
    info.queryCount = kQueriesPerPool;
    VkQueryPool qp;
    SPAR_VK(vkCreateQueryPool(dev, &info, nullptr, &qp));
    queryPools_.push_back(qp);
  }
  if (index == 0) vkCmdResetQueryPool(cmd_, queryPools_[pool], 0, kQueriesPerPool);
  // Bottom-of-pipe stamps after each dispatch: consecutive differences partition the
  // command buffer's time among its dispatches.
  vkCmdWriteTimestamp(cmd_, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, queryPools_[pool], index);
  ++queriesUsed_;
}

VkDescriptorSet Recorder::allocateSet(VkDescriptorSetLayout layout) {
  VkDevice dev = engine_.device().handle();
  for (;; ++currentPool_) {
    if (currentPool_ == descriptorPools_.size()) {
      VkDescriptorPoolSize sizes[2] = {{VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, kSetsPerPool * 6},
                                       {VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER, kSetsPerPool * 6}};
      VkDescriptorPoolCreateInfo info{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
      info.maxSets = kSetsPerPool;
      info.poolSizeCount = 2;
      info.pPoolSizes = sizes;
      VkDescriptorPool p;
      SPAR_VK(vkCreateDescriptorPool(dev, &info, nullptr, &p));
      descriptorPools_.push_back(p);
    }
    VkDescriptorSetAllocateInfo info{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
    info.descriptorPool = descriptorPools_[currentPool_];
    info.descriptorSetCount = 1;
    info.pSetLayouts = &layout;
    VkDescriptorSet set;
    VkResult r = vkAllocateDescriptorSets(dev, &info, &set);
    if (r == VK_SUCCESS) return set;
    if (r != VK_ERROR_OUT_OF_POOL_MEMORY && r != VK_ERROR_FRAGMENTED_POOL) vkCheck(r, "vkAllocateDescriptorSets");
  }
}

bool Recorder::barrierNeeded(const std::vector<Arg>& args) {
  bool hazard = false;
  for (const auto& a : args) {
    VkBuffer b = a.tensor.buffer().handle();
    bool writes = a.kind == Bind::Write || a.kind == Bind::ReadWrite;
    if (writtenSinceBarrier_.count(b) || (writes && readSinceBarrier_.count(b))) hazard = true;
  }
  if (hazard) {
    writtenSinceBarrier_.clear();
    readSinceBarrier_.clear();
    ++barrierCount_;
  }
  for (const auto& a : args) {
    VkBuffer b = a.tensor.buffer().handle();
    if (a.kind == Bind::Write || a.kind == Bind::ReadWrite) writtenSinceBarrier_.insert(b);
    if (a.kind != Bind::Write) readSinceBarrier_.insert(b);
  }
  return hazard;
}

void Recorder::dispatch(const Kernel& kernel, const std::vector<Arg>& args, const void* push, uint32_t pushBytes,
                        uint32_t gx, uint32_t gy, uint32_t gz, const std::string& label) {
  const DeviceCaps& caps = engine_.device().caps();
  const std::string name = label.empty() ? kernel.name : label;
  if (args.size() != kernel.bindings.size())
    throw Error(name + ": " + std::to_string(args.size()) + " arguments for " +
                std::to_string(kernel.bindings.size()) + " bindings");
  if (pushBytes != kernel.pushBytes) throw Error(name + ": push-constant size mismatch");
  if (gx == 0 || gy == 0 || gz == 0) return;  // empty work
  if (gx > caps.maxWorkGroupCount[0] || gy > caps.maxWorkGroupCount[1] || gz > caps.maxWorkGroupCount[2])
    throw Error(name + ": " + std::to_string(gx) + "x" + std::to_string(gy) + "x" + std::to_string(gz) +
                " workgroups exceed the device's limit");

  VkDevice dev = engine_.device().handle();
  Pending d;
  d.kernel = &kernel;
  std::vector<VkDescriptorBufferInfo> bufferInfos(args.size());
  std::vector<VkWriteDescriptorSet> writes(args.size());
  std::vector<VkBufferView> newViews(args.size(), VK_NULL_HANDLE);
  for (size_t i = 0; i < args.size(); ++i) {
    // A texel input of a kernel's storage-input twin (*_sx, engine/kernel_plan.h storageInputs)
    // is bound as a storage buffer of words, fp32 or fp16 (its format joins the signature: the
    // pipeline decodes what it is given).
    Arg a = args[i];
    // Quantized matrices are words only a dequantizing kernel (its name has "_q_") can read: any
    // other would take them for floats.
    if (a.tensor.defined() && isQuantized(a.tensor.dtype()) && kernel.name.find("_q_") == std::string::npos)
      throw Error(name + ": input " + a.tensor.describe() + " is a quantized matrix, which this kernel cannot read");
    if (a.kind == Bind::Texel && kernel.bindings[i] == Bind::StorageInput) {
      if (a.tensor.dtype() != DType::F32 && a.tensor.dtype() != DType::F16 && !isQuantized(a.tensor.dtype()))
        throw Error(name + ": input " + a.tensor.describe() + " is neither fp32, fp16 nor quantized");
      if (a.tensor.bytes() % (dtypeSize(a.tensor.dtype()) * a.components))
        throw Error(name + ": tensor " + a.tensor.describe() + " is not a whole number of " +
                    std::to_string(a.components) + "-element texels");
      a.kind = Bind::StorageInput;
      d.signature += (d.signature.empty() ? "" : ",") + texelTypeName(a.tensor.dtype(), a.components);
    }
    if (!a.tensor.defined()) throw Error(name + ": binding " + std::to_string(i) + " has no tensor");
    if (a.kind != kernel.bindings[i]) throw Error(name + ": binding " + std::to_string(i) + " has the wrong kind");
    const VkDeviceSize offset = a.tensor.byteOffset();
    VkWriteDescriptorSet& w = writes[i];
    w = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET};
    w.dstBinding = static_cast<uint32_t>(i);
    w.descriptorCount = 1;
    if (a.kind == Bind::Texel) {
      const VkDeviceSize texelBytes = dtypeSize(a.tensor.dtype()) * a.components;
      if (a.tensor.dtype() == DType::F16 && !caps.supportsFp16Storage())
        throw Error(name + ": this device cannot read fp16 texel buffers; use fp32");
      if (offset % caps.minTexelBufferOffsetAlignment || a.tensor.bytes() % texelBytes)
        throw Error(name + ": tensor " + a.tensor.describe() + " is not aligned for a texel binding");
      if (a.tensor.bytes() / texelBytes > caps.maxTexelBufferElements)
        throw Error(name + ": tensor " + a.tensor.describe() + " exceeds the device's texel-buffer size; the op must split it");
      VkBufferViewCreateInfo vi{VK_STRUCTURE_TYPE_BUFFER_VIEW_CREATE_INFO};
      vi.buffer = a.tensor.buffer().handle();
      vi.format = texelFormat(a.tensor.dtype(), a.components);
      vi.offset = offset;
      vi.range = stableTexelRange(offset, a.tensor.bytes(), a.tensor.buffer().size(), texelBytes,
                                  caps.maxTexelBufferElements);
      SPAR_VK(vkCreateBufferView(dev, &vi, nullptr, &newViews[i]));
      views_.push_back(newViews[i]);
      w.descriptorType = VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER;
      w.pTexelBufferView = &newViews[i];
      d.signature += (d.signature.empty() ? "" : ",") + texelTypeName(a.tensor.dtype(), a.components);
      d.texelState += texelStateOf(a.tensor.buffer().size(), vi.range);
    } else {
      if ((a.kind == Bind::Write || a.kind == Bind::ReadWrite) && a.tensor.dtype() == DType::F16 &&
          !caps.storageBuffer16BitAccess)
        throw Error(name + ": this device cannot store fp16 buffers; use fp32");
      if (offset % caps.minStorageBufferOffsetAlignment)
        throw Error(name + ": tensor " + a.tensor.describe() + " starts at an offset the device cannot bind");
      if (a.tensor.bytes() > engine_.device().bindingRangeLimit())
        throw Error(name + ": tensor " + a.tensor.describe() + " exceeds the largest storage binding; the op must split it");
      // The binding reaches to the end of the buffer (within the device's range limit), so a
      // kernel writing past its tensor hits the guard words tests place there instead of
      // being silently clipped by a robust driver.
      VkDeviceSize range = std::min<VkDeviceSize>(a.tensor.buffer().size() - offset, engine_.device().bindingRangeLimit());
      bufferInfos[i] = {a.tensor.buffer().handle(), offset, range};
      w.descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
      w.pBufferInfo = &bufferInfos[i];
    }
    keepAlive_.push_back(a.tensor.bufferPtr());
  }
  d.set = allocateSet(kernel.setLayout);
  for (auto& w : writes) w.dstSet = d.set;
  vkUpdateDescriptorSets(dev, static_cast<uint32_t>(writes.size()), writes.data(), 0, nullptr);

  d.barrierBefore = barrierNeeded(args);
  d.push.assign(static_cast<const uint8_t*>(push), static_cast<const uint8_t*>(push) + pushBytes);
  d.groups[0] = gx;
  d.groups[1] = gy;
  d.groups[2] = gz;
  d.label = name;
  d.stage = stage_;
  pending_.push_back(std::move(d));
}

void Recorder::emit(const Pending& d, const Pipeline& pipeline) {
  if (d.barrierBefore) {
    VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER};
    barrier.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT | VK_ACCESS_SHADER_READ_BIT;
    barrier.dstAccessMask = VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT;
    vkCmdPipelineBarrier(cmd_, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, 0, 1,
                         &barrier, 0, nullptr, 0, nullptr);
  }
  vkCmdBindPipeline(cmd_, VK_PIPELINE_BIND_POINT_COMPUTE, pipeline.handle);
  vkCmdBindDescriptorSets(cmd_, VK_PIPELINE_BIND_POINT_COMPUTE, d.kernel->layout, 0, 1, &d.set, 0, nullptr);
  if (!d.push.empty())
    vkCmdPushConstants(cmd_, d.kernel->layout, VK_SHADER_STAGE_COMPUTE_BIT, 0, static_cast<uint32_t>(d.push.size()),
                       d.push.data());
  if (profile_) {
    // The empty dispatch: same pipeline, bindings and push constants, no workgroups. A driver
    // that compiles at dispatch (llvmpipe) does it here, so the stretch up to the next stamp
    // is its build time and the real dispatch after it is compute only.
    vkCmdDispatch(cmd_, 0, 0, 0);
    writeTimestamp();
    // It touches nothing, but a validator sees its bindings' declared access: order it
    // before the real dispatch like any other (synchronization validation stays silent).
    VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER};
    barrier.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT | VK_ACCESS_SHADER_READ_BIT;
    barrier.dstAccessMask = VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT;
    vkCmdPipelineBarrier(cmd_, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, 0, 1,
                         &barrier, 0, nullptr, 0, nullptr);
  }
  vkCmdDispatch(cmd_, d.groups[0], d.groups[1], d.groups[2]);
  if (profile_) writeTimestamp();
}

void Recorder::noteTransformerBlock(uint64_t dispatches) {
  StageCounts& c = blocks_[stage_];
  ++c.transformerBlocks;
  c.blockDispatches = std::max(c.blockDispatches, dispatches);
}

StageCounts Recorder::lastRunTotal() const {
  StageCounts total;
  for (const auto& [stage, counts] : lastCounts_) total += counts;
  return total;
}

void Recorder::run() {
  timings_.clear();
  lastCounts_.clear();
  lastStages_.clear();
  for (const Pending& d : pending_) {
    if (!lastCounts_.count(d.stage)) lastStages_.push_back(d.stage);
    StageCounts& c = lastCounts_[d.stage];
    ++c.dispatches;
    c.barriers += d.barrierBefore;
  }
  for (const auto& [stage, blocks] : blocks_) {
    lastCounts_[stage].transformerBlocks += blocks.transformerBlocks;
    lastCounts_[stage].blockDispatches = std::max(lastCounts_[stage].blockDispatches, blocks.blockDispatches);
  }
  blocks_.clear();
  if (pending_.empty()) return;
  lastCounts_[pending_.back().stage].submits = 1;
  try {
    submitPending();
  } catch (...) {
    // Nothing of a failed batch survives: the next batch starts from an empty recorder.
    vkResetCommandBuffer(cmd_, 0);
    releaseTransient();
    barrierCount_ = 0;
    throw;
  }
}

void Recorder::submitPending() {
  PipelineCache& cache = engine_.pipelines();
  std::vector<std::pair<const Kernel*, std::string>> wanted;
  for (const auto& d : pending_) wanted.emplace_back(d.kernel, d.signature);
  cache.create(wanted);
  std::vector<Pipeline*> pipelines;
  for (const auto& d : pending_) pipelines.push_back(&cache.pipeline(*d.kernel, d.signature));

  VkCommandBufferBeginInfo info{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  info.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  SPAR_VK(vkBeginCommandBuffer(cmd_, &info));
  queriesUsed_ = 0;
  if (profile_) writeTimestamp();
  for (size_t i = 0; i < pending_.size(); ++i) emit(pending_[i], *pipelines[i]);
  // Make every shader write visible to the host reads that follow the fence.
  VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER};
  barrier.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT;
  barrier.dstAccessMask = VK_ACCESS_HOST_READ_BIT | VK_ACCESS_TRANSFER_READ_BIT;
  vkCmdPipelineBarrier(cmd_, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                       VK_PIPELINE_STAGE_HOST_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT, 0, 1, &barrier, 0, nullptr, 0,
                       nullptr);
  SPAR_VK(vkEndCommandBuffer(cmd_));
  VkDevice dev = engine_.device().handle();
  VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
  submit.commandBufferCount = 1;
  submit.pCommandBuffers = &cmd_;
  SPAR_VK(vkResetFences(dev, 1, &fence_));
  SPAR_VK(vkQueueSubmit(engine_.device().queue(), 1, &submit, fence_));
  engine_.waitForSubmission(fence_, [this] {
    return "a submission of " + std::to_string(pending_.size()) + " dispatches" +
           (stage_.empty() ? std::string() : " (stage " + stage_ + ")");
  });

  if (profile_) collectTimings(pipelines);
  SPAR_VK(vkResetCommandBuffer(cmd_, 0));
  releaseTransient();
  barrierCount_ = 0;
}

void Recorder::collectTimings(const std::vector<Pipeline*>& pipelines) {
  VkDevice dev = engine_.device().handle();
  std::vector<uint64_t> stamps(queriesUsed_);
  for (uint32_t done = 0; done < queriesUsed_;) {
    uint32_t pool = done / kQueriesPerPool, n = std::min(kQueriesPerPool, queriesUsed_ - done);
    SPAR_VK(vkGetQueryPoolResults(dev, queryPools_[pool], 0, n, n * sizeof(uint64_t), stamps.data() + done,
                                  sizeof(uint64_t), VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WAIT_BIT));
    done += n;
  }
  const double toMs = engine_.device().caps().timestampPeriodNs * 1e-6;
  auto span = [&](size_t a) { return static_cast<double>(stamps[a + 1] - stamps[a]) * toMs; };
  for (size_t i = 0; i < pending_.size(); ++i) {
    const Pending& d = pending_[i];
    Pipeline& p = *pipelines[i];
    DispatchObservation seen{span(2 * i), span(2 * i + 1), d.texelState, hexOf(d.push)};
    BuildCause cause{};
    if (p.stats.observe(seen, &cause) && engine_.options().logPipelines)
      std::fprintf(stderr, "pipeline %s: driver build %.1f ms at %s (%s)\n", p.name.c_str(), seen.buildMs,
                   d.label.c_str(), buildCauseName(cause));
    timings_.push_back({d.label, d.stage, p.name, seen.ms, seen.buildMs >= kDriverBuildThresholdMs ? seen.buildMs : 0});
  }
}

Tensor Recorder::scratch(int64_t elements) {
  if (!scratch_.defined() || scratch_.numel() < elements) scratch_ = engine_.tensor({elements});
  return scratch_.view(0, {elements});
}

double Recorder::totalMs() const {
  double t = 0;
  for (const auto& d : timings_) t += d.ms;
  return t;
}

double Recorder::totalBuildMs() const {
  double t = 0;
  for (const auto& d : timings_) t += d.buildMs;
  return t;
}

void Recorder::releaseTransient() {
  VkDevice dev = engine_.device().handle();
  for (auto v : views_) vkDestroyBufferView(dev, v, nullptr);
  views_.clear();
  for (auto p : descriptorPools_) vkResetDescriptorPool(dev, p, 0);
  currentPool_ = 0;
  keepAlive_.clear();
  pending_.clear();
  writtenSinceBarrier_.clear();
  readSinceBarrier_.clear();
}

}  // namespace spar
