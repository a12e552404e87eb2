#include "engine/tensor.h"

#include "spar/error.h"

namespace spar {

const char* dtypeName(DType t) {
  switch (t) {
    case DType::F32: return "f32";
    case DType::F16: return "f16";
    case DType::I32: return "i32";
    case DType::Q8: return "q8";
    case DType::Q4: return "q4";
  }
  return "?";
}

std::string shapeString(const Shape& shape) {
  std::string s = "[";
  for (size_t i = 0; i < shape.size(); ++i) s += (i ? ", " : "") + std::to_string(shape[i]);
  return s + "]";
}

uint64_t tensorBytes(const Shape& shape, DType t) {
  const int64_t n = shapeNumel(shape);
  if (!isQuantized(t)) return uint64_t(n) * dtypeSize(t);
  const int64_t k = shape.empty() ? 0 : shape.back();
  if (shape.empty() || k % 32) throw Error(std::string(dtypeName(t)) + shapeString(shape) + ": rows must be whole blocks of 32");
  return k ? uint64_t(n / k) * rowBytes(t, k) : 0;
}

int64_t shapeNumel(const Shape& shape) {
  int64_t n = 1;
  for (auto d : shape) {
    if (d < 0) throw Error("negative dimension in shape " + shapeString(shape));
    n *= d;
  }
  return n;
}

Tensor::Tensor(std::shared_ptr<Buffer> buffer, VkDeviceSize byteOffset, Shape shape, DType dtype)
    : buffer_(std::move(buffer)), offset_(byteOffset), shape_(std::move(shape)), dtype_(dtype) {
  if (buffer_ && offset_ + bytes() > buffer_->size())
    throw Error("tensor " + describe() + " does not fit its buffer");
}

int64_t Tensor::dim(int i) const {
  int r = rank();
  if (i < 0) i += r;
  if (i < 0 || i >= r) throw Error("dimension " + std::to_string(i) + " out of range for " + describe());
  return shape_[i];
}

Tensor Tensor::reshape(Shape shape) const {
  if (shapeNumel(shape) != numel())
    throw Error("cannot reshape " + describe() + " to " + shapeString(shape));
  return Tensor(buffer_, offset_, std::move(shape), dtype_);
}

Tensor Tensor::view(int64_t elementOffset, Shape shape) const {
  if (elementOffset < 0 || elementOffset + shapeNumel(shape) > numel())
    throw Error("view at " + std::to_string(elementOffset) + " of " + shapeString(shape) + " exceeds " + describe());
  if (isQuantized(dtype_)) {
    const int64_t k = shape_.back();
    if (shape.empty() || shape.back() != k || elementOffset % k)
      throw Error("view at " + std::to_string(elementOffset) + " of " + shapeString(shape) + " is not whole rows of " +
                  describe());
    return Tensor(buffer_, offset_ + static_cast<VkDeviceSize>(elementOffset / k) * rowBytes(dtype_, k), std::move(shape),
                  dtype_);
  }
  return Tensor(buffer_, offset_ + static_cast<VkDeviceSize>(elementOffset) * dtypeSize(dtype_), std::move(shape), dtype_);
}

std::string Tensor::describe() const { return std::string(dtypeName(dtype_)) + shapeString(shape_); }

}  // namespace spar
