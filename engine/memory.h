// Device memory: large blocks sub-allocated for buffers (first fit, coalescing free
// list), so a model with hundreds of tensors makes a handful of vkAllocateMemory calls.
#pragma once
#include <vulkan/vulkan.h>

#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "engine/device.h"

namespace spar {

enum class MemoryUsage {
  Tensor,   // what kernels read and write: device-local (host-visible too where the device has it)
  Staging,  // host-visible memory for uploads and downloads on devices without the above
};

struct Allocation {
  uint32_t block = UINT32_MAX;
  VkDeviceSize offset = 0;
  VkDeviceSize size = 0;
  bool valid() const { return block != UINT32_MAX; }
};

class MemoryAllocator {
 public:
  explicit MemoryAllocator(Device& device, VkDeviceSize blockSize = 256ull << 20);
  ~MemoryAllocator();
  MemoryAllocator(const MemoryAllocator&) = delete;
  MemoryAllocator& operator=(const MemoryAllocator&) = delete;

  Allocation allocate(const VkMemoryRequirements& requirements, MemoryUsage usage);
  void release(const Allocation& allocation);

  VkDeviceMemory memory(const Allocation& a) const { return blocks_[a.block].memory; }
  // Host address of the allocation, or nullptr where its memory is not mappable.
  void* mapped(const Allocation& a) const;

  // Test hook (EngineOptions::faults): allocation number n (from 1) fails as out of memory.
  void failAllocation(uint64_t n) { failAt_ = n; }
  uint64_t allocations() const { return allocations_; }
  // At most `bytes` in use at once (0: no limit beyond the device's); over it is out of memory.
  // `source` names where the limit comes from, in errors.
  void limit(VkDeviceSize bytes, std::string source) {
    limit_ = bytes;
    limitSource_ = std::move(source);
  }
  // What a request may use: the limit, else the largest device-local heap; and which of the
  // two that is, in words (for errors).
  VkDeviceSize budget() const;
  std::string budgetSource() const;

  VkDeviceSize bytesInUse() const { return inUse_; }
  VkDeviceSize peakBytes() const { return peak_; }
  VkDeviceSize bytesReserved() const;

 private:
  struct Block {
    VkDeviceMemory memory = VK_NULL_HANDLE;
    VkDeviceSize size = 0;
    uint32_t memoryType = 0;
    void* mapped = nullptr;
    std::map<VkDeviceSize, VkDeviceSize> freeRanges;  // offset -> size
  };
  uint32_t chooseMemoryType(uint32_t typeBits, MemoryUsage usage) const;
  uint32_t addBlock(VkDeviceSize size, uint32_t memoryType);

  Device& device_;
  VkDeviceSize blockSize_;
  std::vector<Block> blocks_;
  VkDeviceSize inUse_ = 0, peak_ = 0;
  uint64_t allocations_ = 0, failAt_ = 0;
  VkDeviceSize limit_ = 0;
  std::string limitSource_;
  // "cannot allocate ...: <why>" with what is in use and the heap's size, so that a request too
  // large for the device says how much it asked for.
  std::string outOfMemory(VkDeviceSize bytes, uint32_t memoryType, const std::string& why) const;
};

// A VkBuffer bound to a sub-allocation. Usable as storage buffer, uniform texel buffer
// and transfer source/destination.
class Buffer {
 public:
  Buffer(Device& device, MemoryAllocator& allocator, VkDeviceSize bytes, MemoryUsage usage);
  ~Buffer();
  Buffer(const Buffer&) = delete;
  Buffer& operator=(const Buffer&) = delete;

  VkBuffer handle() const { return buffer_; }
  VkDeviceSize size() const { return size_; }
  void* mapped() const { return allocator_.mapped(allocation_); }

 private:
  Device& device_;
  MemoryAllocator& allocator_;
  VkBuffer buffer_ = VK_NULL_HANDLE;
  VkDeviceSize size_ = 0;
  Allocation allocation_;
};

}  // namespace spar
