// Strided 2-D copy, concatenation and slicing; the kernel is shaders/copy2d.comp.
#include "engine/ops/copy2d.h"

#include "engine/ops/binding_range.h"
#include "engine/ops/dispatch_helpers.h"

namespace spar {
namespace {

struct Copy2dPush {
  uint32_t rows, cols;
  uint32_t srcStride, srcCol;
  uint32_t dstStride, dstCol;
};

// [outer, extent along axis, inner] around `axis` of t.
struct AxisSplit {
  int64_t outer = 1, extent = 1, inner = 1;
};

int normalizeAxis(const Tensor& t, int axis, const std::string& op) {
  const int r = t.rank();
  if (axis < -r || axis >= r) throw Error(op + ": axis " + std::to_string(axis) + " out of range for " + t.describe());
  return axis < 0 ? axis + r : axis;
}

AxisSplit splitAt(const Tensor& t, int axis) {
  AxisSplit s;
  for (int i = 0; i < axis; ++i) s.outer *= t.dim(i);
  s.extent = t.dim(axis);
  for (int i = axis + 1; i < t.rank(); ++i) s.inner *= t.dim(i);
  return s;
}

// Same shape except along `axis`.
bool sameExceptAxis(const Tensor& a, const Tensor& b, int axis) {
  if (a.rank() != b.rank()) return false;
  for (int i = 0; i < a.rank(); ++i)
    if (i != axis && a.dim(i) != b.dim(i)) return false;
  return true;
}

}  // namespace

void copy2d(Recorder& rec, const Tensor& src, int64_t srcStride, int64_t srcCol, const Tensor& dst, int64_t dstStride,
            int64_t dstCol, int64_t rows, int64_t cols) {
  const std::string op = "copy2d";
  Engine& engine = rec.engine();
  ops::requireF32(src, op, "src");
  ops::requireF32(dst, op, "dst");
  if (rows < 0 || cols < 0 || srcCol < 0 || dstCol < 0) throw Error(op + ": negative size or column");
  if (rows == 0 || cols == 0) return;
  if (srcStride < srcCol + cols || dstStride < dstCol + cols) throw Error(op + ": columns exceed the row stride");
  if ((rows - 1) * srcStride + srcCol + cols > src.numel())
    throw Error(op + ": " + std::to_string(rows) + " rows of stride " + std::to_string(srcStride) + " exceed src " +
                src.describe());
  if ((rows - 1) * dstStride + dstCol + cols > dst.numel())
    throw Error(op + ": " + std::to_string(rows) + " rows of stride " + std::to_string(dstStride) + " exceed dst " +
                dst.describe());
  if (ops::overlaps(src, dst)) throw Error(op + ": src and dst overlap");
  if (uint64_t(rows) * uint64_t(cols) > 0x7fffffffull) throw Error(op + ": too many values for 32-bit indexing");

  // Bindings start where the device allows (ops::bindRange), at or before a chunk's first row;
  // the column offsets carry the difference, a whole number of vec4s when both tensors start
  // on 16 bytes.
  const bool vec4 = cols % 4 == 0 && srcStride % 4 == 0 && srcCol % 4 == 0 && dstStride % 4 == 0 && dstCol % 4 == 0 &&
                    src.byteOffset() % 16 == 0 && dst.byteOffset() % 16 == 0;
  const Kernel& kernel =
      engine.kernel({"copy2d", {Bind::Read, Bind::Write}, sizeof(Copy2dPush), {ops::elementLocalX(engine.caps()), 1, 1, vec4}});
  // Chunks of whole rows; the last row of a tensor may stop short of a full stride.
  for (auto [r0, n] : ops::rowChunks(engine, rows, {uint64_t(srcStride) * 4, uint64_t(dstStride) * 4}, op)) {
    const int64_t srcLen = std::min(n * srcStride, src.numel() - r0 * srcStride);
    const int64_t dstLen = std::min(n * dstStride, dst.numel() - r0 * dstStride);
    const ops::BoundRange sc = ops::bindRange(engine.caps(), src.reshape({src.numel()}), r0 * srcStride, r0 * srcStride + srcLen, false);
    const ops::BoundRange dc = ops::bindRange(engine.caps(), dst.reshape({dst.numel()}), r0 * dstStride, r0 * dstStride + dstLen, false);
    const int64_t srcShift = r0 * srcStride - sc.base, dstShift = r0 * dstStride - dc.base;
    const Copy2dPush push{uint32_t(n),      uint32_t(cols),      uint32_t(srcStride),
                          uint32_t(srcCol + srcShift), uint32_t(dstStride), uint32_t(dstCol + dstShift)};
    const ops::Grid grid = ops::linearGrid(
        engine.caps(), ops::ceilDiv(uint64_t(n) * cols, vec4 ? ops::elementsPerGroup(engine.caps()) : uint64_t(ops::elementLocalX(engine.caps()))),
        op);
    rec.dispatch(kernel, {Arg::in(sc.view), Arg::out(dc.view)}, push, grid.x, grid.y, 1, op);
  }
}

void concat(Recorder& rec, const std::vector<Tensor>& parts, const Tensor& out, int axis) {
  const std::string op = "concat";
  if (!out.defined()) throw Error(op + ": out is missing");
  axis = normalizeAxis(out, axis, op);
  int64_t total = 0;
  for (const Tensor& p : parts) {
    if (!p.defined() || !sameExceptAxis(p, out, axis))
      throw Error(op + ": part " + (p.defined() ? p.describe() : std::string("(none)")) + " does not fit " +
                  out.describe() + " along axis " + std::to_string(axis));
    total += p.dim(axis);
  }
  if (total != out.dim(axis))
    throw Error(op + ": parts add up to " + std::to_string(total) + " along axis " + std::to_string(axis) + ", out " +
                out.describe() + " has " + std::to_string(out.dim(axis)));
  const AxisSplit o = splitAt(out, axis);
  int64_t offset = 0;
  for (const Tensor& p : parts) {
    const int64_t block = p.dim(axis) * o.inner;
    copy2d(rec, p, block, 0, out, o.extent * o.inner, offset * o.inner, o.outer, block);
    offset += p.dim(axis);
  }
}

void slice(Recorder& rec, const Tensor& in, int axis, int64_t start, int64_t length, const Tensor& out) {
  const std::string op = "slice";
  if (!in.defined() || !out.defined()) throw Error(op + ": missing tensor");
  axis = normalizeAxis(in, axis, op);
  if (start < 0 || length < 0 || start + length > in.dim(axis))
    throw Error(op + ": [" + std::to_string(start) + ", " + std::to_string(start + length) + ") outside axis " +
                std::to_string(axis) + " of " + in.describe());
  if (!sameExceptAxis(in, out, axis) || out.dim(axis) != length)
    throw Error(op + ": out " + out.describe() + " should be " + in.describe() + " with " + std::to_string(length) +
                " along axis " + std::to_string(axis));
  const AxisSplit s = splitAt(in, axis);
  copy2d(rec, in, s.extent * s.inner, start * s.inner, out, length * s.inner, 0, s.outer, length * s.inner);
}

}  // namespace spar
