#include "engine/recorder.h"

#include <algorithm>

#include "engine/engine.h"
#include "engine/error.h"

namespace spar {
namespace {

constexpr uint32_t kQueriesPerPool = 1024;
constexpr uint32_t kSetsPerPool = 512;

VkFormat texelFormat(DType dtype, int components) {
  if (dtype == DType::F32) return components == 4 ? VK_FORMAT_R32G32B32A32_SFLOAT : VK_FORMAT_R32_SFLOAT;
  if (dtype == DType::F16) return components == 4 ? VK_FORMAT_R16G16B16A16_SFLOAT : VK_FORMAT_R16_SFLOAT;
  return components == 4 ? VK_FORMAT_R32G32B32A32_SINT : VK_FORMAT_R32_SINT;
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
  if (recording_) vkEndCommandBuffer(cmd_);  // abandoned recording: never submitted
  releaseTransient();
  for (auto p : descriptorPools_) vkDestroyDescriptorPool(dev, p, nullptr);
  for (auto q : queryPools_) vkDestroyQueryPool(dev, q, nullptr);
  vkDestroyFence(dev, fence_, nullptr);
  vkDestroyCommandPool(dev, pool_, nullptr);
}

void Recorder::begin() {
  VkCommandBufferBeginInfo info{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  info.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  SPAR_VK(vkBeginCommandBuffer(cmd_, &info));
  recording_ = true;
  queriesUsed_ = 0;
  labels_.clear();
  stages_.clear();
  writtenSinceBarrier_.clear();
  readSinceBarrier_.clear();
  if (profile_) writeTimestamp();
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

void Recorder::barrierIfNeeded(const std::vector<Arg>& args) {
  bool hazard = false;
  for (const auto& a : args) {
    VkBuffer b = a.tensor.buffer().handle();
    bool writes = a.kind == Bind::Write || a.kind == Bind::ReadWrite;
    if (writtenSinceBarrier_.count(b) || (writes && readSinceBarrier_.count(b))) hazard = true;
  }
  if (hazard) {
    VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER};
    barrier.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT | VK_ACCESS_SHADER_READ_BIT;
    barrier.dstAccessMask = VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT;
    vkCmdPipelineBarrier(cmd_, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, 0, 1,
                         &barrier, 0, nullptr, 0, nullptr);
    writtenSinceBarrier_.clear();
    readSinceBarrier_.clear();
    ++barrierCount_;
  }
  for (const auto& a : args) {
    VkBuffer b = a.tensor.buffer().handle();
    if (a.kind == Bind::Write || a.kind == Bind::ReadWrite) writtenSinceBarrier_.insert(b);
    if (a.kind != Bind::Write) readSinceBarrier_.insert(b);
  }
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
  if (!recording_) begin();

  VkDevice dev = engine_.device().handle();
  VkDescriptorSet set = allocateSet(kernel.setLayout);
  std::vector<VkDescriptorBufferInfo> bufferInfos(args.size());
  std::vector<VkWriteDescriptorSet> writes(args.size());
  std::vector<VkBufferView> newViews(args.size(), VK_NULL_HANDLE);
  for (size_t i = 0; i < args.size(); ++i) {
    const Arg& a = args[i];
    if (!a.tensor.defined()) throw Error(name + ": binding " + std::to_string(i) + " has no tensor");
    if (a.kind != kernel.bindings[i]) throw Error(name + ": binding " + std::to_string(i) + " has the wrong kind");
    const VkDeviceSize offset = a.tensor.byteOffset();
    VkWriteDescriptorSet& w = writes[i];
    w = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET};
    w.dstSet = set;
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
      vi.range = a.tensor.bytes();
      SPAR_VK(vkCreateBufferView(dev, &vi, nullptr, &newViews[i]));
      views_.push_back(newViews[i]);
      w.descriptorType = VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER;
      w.pTexelBufferView = &newViews[i];
    } else {
      if ((a.kind != Bind::Read) && a.tensor.dtype() == DType::F16 && !caps.storageBuffer16BitAccess)
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
  vkUpdateDescriptorSets(dev, static_cast<uint32_t>(writes.size()), writes.data(), 0, nullptr);

  barrierIfNeeded(args);
  vkCmdBindPipeline(cmd_, VK_PIPELINE_BIND_POINT_COMPUTE, kernel.pipeline);
  vkCmdBindDescriptorSets(cmd_, VK_PIPELINE_BIND_POINT_COMPUTE, kernel.layout, 0, 1, &set, 0, nullptr);
  if (pushBytes) vkCmdPushConstants(cmd_, kernel.layout, VK_SHADER_STAGE_COMPUTE_BIT, 0, pushBytes, push);
  vkCmdDispatch(cmd_, gx, gy, gz);
  ++dispatchCount_;
  if (profile_) {
    writeTimestamp();
    labels_.push_back(name);
    stages_.push_back(stage_);
  }
}

void Recorder::run() {
  timings_.clear();
  if (!recording_) return;
  // Make every shader write visible to the host reads that follow the fence.
  VkMemoryBarrier barrier{VK_STRUCTURE_TYPE_MEMORY_BARRIER};
  barrier.srcAccessMask = VK_ACCESS_SHADER_WRITE_BIT;
  barrier.dstAccessMask = VK_ACCESS_HOST_READ_BIT | VK_ACCESS_TRANSFER_READ_BIT;
  vkCmdPipelineBarrier(cmd_, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                       VK_PIPELINE_STAGE_HOST_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT, 0, 1, &barrier, 0, nullptr, 0,
                       nullptr);
  SPAR_VK(vkEndCommandBuffer(cmd_));
  recording_ = false;
  VkDevice dev = engine_.device().handle();
  VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
  submit.commandBufferCount = 1;
  submit.pCommandBuffers = &cmd_;
  SPAR_VK(vkResetFences(dev, 1, &fence_));
  SPAR_VK(vkQueueSubmit(engine_.device().queue(), 1, &submit, fence_));
  SPAR_VK(vkWaitForFences(dev, 1, &fence_, VK_TRUE, UINT64_MAX));

  if (profile_ && queriesUsed_ > 1) {
    std::vector<uint64_t> stamps(queriesUsed_);
    for (uint32_t done = 0; done < queriesUsed_;) {
      uint32_t pool = done / kQueriesPerPool, n = std::min(kQueriesPerPool, queriesUsed_ - done);
      SPAR_VK(vkGetQueryPoolResults(dev, queryPools_[pool], 0, n, n * sizeof(uint64_t), stamps.data() + done,
                                    sizeof(uint64_t), VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WAIT_BIT));
      done += n;
    }
    const double period = engine_.device().caps().timestampPeriodNs;
    for (size_t i = 0; i + 1 < stamps.size(); ++i)
      timings_.push_back({labels_[i], stages_[i], static_cast<double>(stamps[i + 1] - stamps[i]) * period * 1e-6});
  }
  SPAR_VK(vkResetCommandBuffer(cmd_, 0));
  releaseTransient();
  dispatchCount_ = 0;
  barrierCount_ = 0;
}

double Recorder::totalMs() const {
  double t = 0;
  for (const auto& d : timings_) t += d.ms;
  return t;
}

void Recorder::releaseTransient() {
  VkDevice dev = engine_.device().handle();
  for (auto v : views_) vkDestroyBufferView(dev, v, nullptr);
  views_.clear();
  for (auto p : descriptorPools_) vkResetDescriptorPool(dev, p, 0);
  currentPool_ = 0;
  keepAlive_.clear();
}

}  // namespace spar
