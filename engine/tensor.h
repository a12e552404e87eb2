// A typed, shaped view of a device buffer. Copies share the buffer (views, reshapes).
#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "engine/memory.h"

namespace spar {

enum class DType { F32, F16, I32 };

inline size_t dtypeSize(DType t) { return t == DType::F16 ? 2 : 4; }
const char* dtypeName(DType t);

using Shape = std::vector<int64_t>;
std::string shapeString(const Shape& shape);
int64_t shapeNumel(const Shape& shape);

class Tensor {
 public:
  Tensor() = default;
  Tensor(std::shared_ptr<Buffer> buffer, VkDeviceSize byteOffset, Shape shape, DType dtype);

  bool defined() const { return buffer_ != nullptr; }
  const Shape& shape() const { return shape_; }
  DType dtype() const { return dtype_; }
  int rank() const { return static_cast<int>(shape_.size()); }
  int64_t dim(int i) const;  // negative counts from the end
  int64_t numel() const { return shapeNumel(shape_); }
  VkDeviceSize bytes() const { return static_cast<VkDeviceSize>(numel()) * dtypeSize(dtype_); }
  VkDeviceSize byteOffset() const { return offset_; }
  Buffer& buffer() const { return *buffer_; }
  const std::shared_ptr<Buffer>& bufferPtr() const { return buffer_; }

  // Same bytes, another shape of the same element count.
  Tensor reshape(Shape shape) const;
  // A contiguous sub-range starting elementOffset elements in.
  Tensor view(int64_t elementOffset, Shape shape) const;
  std::string describe() const;  // "f32[2, 3]"

 private:
  std::shared_ptr<Buffer> buffer_;
  VkDeviceSize offset_ = 0;
  Shape shape_;
  DType dtype_ = DType::F32;
};

}  // namespace spar
