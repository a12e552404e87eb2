#include "engine/memory.h"

#include <algorithm>
#include <cstdio>
#include <string>

#include "engine/vk_result.h"
#include "engine/host_pages.h"

namespace spar {
namespace {
VkDeviceSize alignUp(VkDeviceSize v, VkDeviceSize a) { return (v + a - 1) / a * a; }
}  // namespace

MemoryAllocator::MemoryAllocator(Device& device, VkDeviceSize blockSize) : device_(device), blockSize_(blockSize) {}

MemoryAllocator::~MemoryAllocator() {
  for (auto& b : blocks_) {
    if (b.mapped) vkUnmapMemory(device_.handle(), b.memory);
    if (b.memory) vkFreeMemory(device_.handle(), b.memory, nullptr);
  }
}

uint32_t MemoryAllocator::chooseMemoryType(uint32_t typeBits, MemoryUsage usage) const {
  const auto& mem = device_.memoryProperties();
  const VkMemoryPropertyFlags local = VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT;
  const VkMemoryPropertyFlags host = VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
  std::vector<VkMemoryPropertyFlags> wanted;
  if (usage == MemoryUsage::Tensor) {
    if (device_.caps().hostVisibleDeviceLocal) wanted.push_back(local | host);
    wanted.push_back(local);
  } else {
    wanted.push_back(host | VK_MEMORY_PROPERTY_HOST_CACHED_BIT);
    wanted.push_back(host);
  }
  for (auto flags : wanted)
    for (uint32_t i = 0; i < mem.memoryTypeCount; ++i)
      if ((typeBits & (1u << i)) && (mem.memoryTypes[i].propertyFlags & flags) == flags) return i;
  throw Error("no suitable Vulkan memory type for a buffer");
}

uint32_t MemoryAllocator::addBlock(VkDeviceSize size, uint32_t memoryType) {
  Block block;
  block.size = size;
  block.memoryType = memoryType;
  VkMemoryAllocateInfo info{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
  info.allocationSize = size;
  info.memoryTypeIndex = memoryType;
  VkResult r = vkAllocateMemory(device_.handle(), &info, nullptr, &block.memory);
  if (r != VK_SUCCESS) throw Error(outOfMemory(size, memoryType, describeVkResult(r)));
  if (device_.memoryProperties().memoryTypes[memoryType].propertyFlags & VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT) {
    SPAR_VK(vkMapMemory(device_.handle(), block.memory, 0, VK_WHOLE_SIZE, 0, &block.mapped));
    // a CPU device's memory is process memory not touched yet: huge pages, fewer faults
    if (device_.caps().isCpu()) adviseHugePages(block.mapped, size_t(size));
  }
  block.freeRanges[0] = size;
  blocks_.push_back(std::move(block));
  return static_cast<uint32_t>(blocks_.size() - 1);
}

std::string MemoryAllocator::outOfMemory(VkDeviceSize bytes, uint32_t memoryType, const std::string& why) const {
  const auto& props = device_.memoryProperties();
  const VkDeviceSize heap = props.memoryHeaps[props.memoryTypes[memoryType].heapIndex].size;
  auto mib = [](VkDeviceSize b) {
    char text[32];
    std::snprintf(text, sizeof(text), "%.1f MiB", double(b) / double(1 << 20));
    return std::string(text);
  };
  return "cannot allocate " + mib(bytes) + " of device memory with " + mib(inUse_) + " in use (device heap " +
         mib(heap) + "): " + why;
}

VkDeviceSize MemoryAllocator::budget() const {
  const auto& props = device_.memoryProperties();
  VkDeviceSize heap = 0;
  for (uint32_t i = 0; i < props.memoryHeapCount; ++i)
    if (props.memoryHeaps[i].flags & VK_MEMORY_HEAP_DEVICE_LOCAL_BIT) heap = std::max(heap, props.memoryHeaps[i].size);
  return limit_ ? (heap ? std::min(limit_, heap) : limit_) : heap;
}

std::string MemoryAllocator::budgetSource() const {
  return limit_ && budget() == limit_ ? limitSource_ : "the device's largest memory heap";
}

Allocation MemoryAllocator::allocate(const VkMemoryRequirements& req, MemoryUsage usage) {
  uint32_t type = chooseMemoryType(req.memoryTypeBits, usage);
  if (++allocations_ == failAt_)
    throw Error(outOfMemory(req.size, type,
                            "VK_ERROR_OUT_OF_DEVICE_MEMORY (injected: allocation " + std::to_string(failAt_) + ")"));
  if (limit_ && inUse_ + req.size > limit_)
    throw Error(outOfMemory(req.size, type, "over the memory limit of " + std::to_string(limit_ >> 20) +
                                                " MiB (" + limitSource_ + ")"));
  const VkDeviceSize maxAlloc = device_.caps().maxMemoryAllocationSize;
  if (maxAlloc && req.size > maxAlloc)
    throw Error("a buffer of " + std::to_string(req.size >> 20) + " MiB exceeds the device's largest allocation (" +
                std::to_string(maxAlloc >> 20) + " MiB)");
  for (uint32_t bi = 0; bi < blocks_.size(); ++bi) {
    Block& b = blocks_[bi];
    if (b.memoryType != type) continue;
    for (auto it = b.freeRanges.begin(); it != b.freeRanges.end(); ++it) {
      VkDeviceSize start = alignUp(it->first, req.alignment);
      VkDeviceSize end = it->first + it->second;
      if (start + req.size > end) continue;
      VkDeviceSize rangeStart = it->first;
      b.freeRanges.erase(it);
      if (start > rangeStart) b.freeRanges[rangeStart] = start - rangeStart;
      if (start + req.size < end) b.freeRanges[start + req.size] = end - (start + req.size);
      inUse_ += req.size;
      peak_ = std::max(peak_, inUse_);
      return {bi, start, req.size};
    }
  }
  VkDeviceSize size = std::max(blockSize_, alignUp(req.size, 1 << 20));
  if (maxAlloc) size = std::min(size, maxAlloc);
  uint32_t bi = addBlock(size, type);
  Block& b = blocks_[bi];
  b.freeRanges.clear();
  if (req.size < size) b.freeRanges[req.size] = size - req.size;
  inUse_ += req.size;
  peak_ = std::max(peak_, inUse_);
  return {bi, 0, req.size};
}

void MemoryAllocator::release(const Allocation& a) {
  if (!a.valid()) return;
  Block& b = blocks_[a.block];
  VkDeviceSize start = a.offset, size = a.size;
  auto next = b.freeRanges.lower_bound(start);
  if (next != b.freeRanges.end() && next->first == start + size) {
    size += next->second;
    next = b.freeRanges.erase(next);
  }
  if (next != b.freeRanges.begin()) {
    auto prev = std::prev(next);
    if (prev->first + prev->second == start) {
      start = prev->first;
      size += prev->second;
      b.freeRanges.erase(prev);
    }
  }
  b.freeRanges[start] = size;
  inUse_ -= a.size;
}

void* MemoryAllocator::mapped(const Allocation& a) const {
  const Block& b = blocks_[a.block];
  return b.mapped ? static_cast<char*>(b.mapped) + a.offset : nullptr;
}

VkDeviceSize MemoryAllocator::bytesReserved() const {
  VkDeviceSize total = 0;
  for (const auto& b : blocks_) total += b.size;
  return total;
}

Buffer::Buffer(Device& device, MemoryAllocator& allocator, VkDeviceSize bytes, MemoryUsage usage)
    : device_(device), allocator_(allocator), size_(bytes) {
  if (bytes == 0) throw Error("cannot create an empty buffer");
  VkBufferCreateInfo info{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
  info.size = bytes;
  info.usage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT |
               VK_BUFFER_USAGE_TRANSFER_SRC_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT;
  info.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  SPAR_VK(vkCreateBuffer(device.handle(), &info, nullptr, &buffer_));
  try {
    VkMemoryRequirements req;
    vkGetBufferMemoryRequirements(device.handle(), buffer_, &req);
    allocation_ = allocator.allocate(req, usage);
    SPAR_VK(vkBindBufferMemory(device.handle(), buffer_, allocator.memory(allocation_), allocation_.offset));
  } catch (...) {
    allocator_.release(allocation_);
    vkDestroyBuffer(device.handle(), buffer_, nullptr);
    throw;
  }
}

Buffer::~Buffer() {
  vkDestroyBuffer(device_.handle(), buffer_, nullptr);
  allocator_.release(allocation_);
}

}  // namespace spar
