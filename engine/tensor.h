// A typed, shaped view of a device buffer. Copies share the buffer (views, reshapes).
#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "engine/memory.h"

namespace spar {

using Shape = std::vector<int64_t>;

// Q8 / Q4: a block-quantized weight matrix [N, K] (converter/FORMAT.md, "Quantized matrices"):
// each row is K/32 blocks of int8 (Q8) or 4-bit (Q4) codes packed in 32-bit words, then the
// row's K/32 float32 scales; K is a multiple of 32. Only whole rows are viewed.
enum class DType { F32, F16, I32, Q8, Q4 };

inline bool isQuantized(DType t) { return t == DType::Q8 || t == DType::Q4; }
// Bytes of one element; for Q8 / Q4 the 32-bit word their rows are read in.
inline size_t dtypeSize(DType t) { return t == DType::F16 ? 2 : 4; }
// Bytes of a row of K elements: K * dtypeSize, and for Q8 / Q4 the codes and the scales.
inline uint64_t rowBytes(DType t, int64_t k) {
  if (t == DType::Q8) return uint64_t(k) + uint64_t(k) / 8;      // 32 codes + one scale: 36 bytes
  if (t == DType::Q4) return uint64_t(k) / 2 + uint64_t(k) / 8;  // 16 bytes of codes + 4: 20
  return uint64_t(k) * dtypeSize(t);
}
// Bytes of a tensor of `shape` (rows of its last dimension for Q8 / Q4).
uint64_t tensorBytes(const Shape& shape, DType t);
const char* dtypeName(DType t);

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
  VkDeviceSize bytes() const { return tensorBytes(shape_, dtype_); }
  VkDeviceSize byteOffset() const { return offset_; }
  Buffer& buffer() const { return *buffer_; }
  const std::shared_ptr<Buffer>& bufferPtr() const { return buffer_; }

  // Same bytes, another shape of the same element count.
  Tensor reshape(Shape shape) const;
  // A contiguous sub-range starting elementOffset elements in (for Q8 / Q4 at a row's start, of
  // whole rows of the same length).
  Tensor view(int64_t elementOffset, Shape shape) const;
  std::string describe() const;  // "f32[2, 3]"

 private:
  std::shared_ptr<Buffer> buffer_;
  VkDeviceSize offset_ = 0;
  Shape shape_;
  DType dtype_ = DType::F32;
};

}  // namespace spar
