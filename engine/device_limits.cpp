// How a device-limit profile (include/spar/device_limits.h) tightens the capabilities the engine
// read off the device (engine/device_limits.h). The profiles themselves: api/device_limits.cpp.
#include "engine/device_limits.h"

#include <algorithm>

namespace spar {
namespace {

template <class T>
void tighten(T& have, const std::optional<T>& limit) {
  if (limit) have = std::min(have, *limit);
}

void off(bool& have, const std::optional<bool>& feature) {
  if (feature && !*feature) have = false;
}

}  // namespace

void tightenCaps(DeviceCaps& caps, const DeviceLimits& l) {
  if (l.empty()) return;
  caps.limitsProfile = l.name;
  tighten<uint64_t>(caps.maxTexelBufferElements, l.maxTexelBufferElements);
  tighten<uint64_t>(caps.maxStorageBufferRange, l.maxStorageBufferRange);
  if (l.maxMemoryAllocationSize)
    caps.maxMemoryAllocationSize = caps.maxMemoryAllocationSize ? std::min<uint64_t>(caps.maxMemoryAllocationSize, *l.maxMemoryAllocationSize)
                                                                : *l.maxMemoryAllocationSize;
  tighten<uint32_t>(caps.maxSharedMemory, l.maxComputeSharedMemorySize);
  tighten<uint32_t>(caps.maxWorkGroupInvocations, l.maxComputeWorkGroupInvocations);
  for (uint32_t& c : caps.maxWorkGroupCount) tighten<uint32_t>(c, l.maxComputeWorkGroupCount);
  tighten<uint32_t>(caps.maxPushConstantsSize, l.maxPushConstantsSize);
  tighten<uint32_t>(caps.maxPerStageStorageBuffers, l.maxPerStageDescriptorStorageBuffers);
  tighten<uint32_t>(caps.maxPerStageSampledImages, l.maxPerStageDescriptorSampledImages);
  if (l.minStorageBufferOffsetAlignment)
    caps.minStorageBufferOffsetAlignment = std::max<uint64_t>(caps.minStorageBufferOffsetAlignment, *l.minStorageBufferOffsetAlignment);
  if (l.minTexelBufferOffsetAlignment)
    caps.minTexelBufferOffsetAlignment = std::max<uint64_t>(caps.minTexelBufferOffsetAlignment, *l.minTexelBufferOffsetAlignment);
  off(caps.shaderFloat16, l.shaderFloat16);
  off(caps.storageBuffer16BitAccess, l.storageBuffer16BitAccess);
  off(caps.fp16TexelBuffers, l.storageBuffer16BitAccess);
  off(caps.subgroupArithmetic, l.subgroupArithmetic);
  off(caps.cooperativeMatrix, l.cooperativeMatrix);
  if (!caps.cooperativeMatrix) caps.coopMatSizes.clear();
  if (l.subgroupSizeControl && !*l.subgroupSizeControl) {
    caps.fullSubgroups = false;
    caps.requiredSubgroupSize = false;
    caps.minSubgroupSize = caps.maxSubgroupSize = caps.subgroupSize;
    caps.cooperativeMatrix = false;  // its kernels need full subgroups
    caps.coopMatSizes.clear();
  }
}

}  // namespace spar
