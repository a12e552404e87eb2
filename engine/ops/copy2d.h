// Strided 2-D copies (fp32) on shaders/copy2d.comp: concatenation and slicing along an axis.
#pragma once
#include <vector>

#include "engine/recorder.h"

namespace spar {

// dst[r * dstStride + dstCol + c] = src[r * srcStride + srcCol + c] for r < rows, c < cols,
// in elements of the flat tensors. src and dst must not overlap.
void copy2d(Recorder& rec, const Tensor& src, int64_t srcStride, int64_t srcCol, const Tensor& dst, int64_t dstStride,
            int64_t dstCol, int64_t rows, int64_t cols);

// out = torch.cat(parts, dim=axis): every part has out's shape except along `axis`, where
// the parts' extents add up to out's. One dispatch per part.
void concat(Recorder& rec, const std::vector<Tensor>& parts, const Tensor& out, int axis);

// out = in.narrow(axis, start, length): out has in's shape with `length` along `axis`.
void slice(Recorder& rec, const Tensor& in, int axis, int64_t start, int64_t length, const Tensor& out);

// The same along the last dimension of [R, C] tensors (columns / channels-last).
inline void concatColumns(Recorder& rec, const std::vector<Tensor>& parts, const Tensor& out) {
  concat(rec, parts, out, -1);
}
inline void sliceColumns(Recorder& rec, const Tensor& in, int64_t col0, int64_t cols, const Tensor& out) {
  slice(rec, in, -1, col0, cols, out);
}

}  // namespace spar
