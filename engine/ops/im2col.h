// The patches of a 2-D convolution as the rows of a matrix (shaders/im2col.comp), for the
// convolutions that run as a GEMM on the lanes GEMM (KernelPlan::gemmLanesSplitK, SwiftShader):
// conv2d (engine/ops/conv2d.cpp) and conv_transpose2d (engine/ops/conv_transpose2d.cpp, whose
// input and kernel it transposes, as 1x1 patches).
#pragma once
#include <cstdint>

#include "engine/recorder.h"

namespace spar::ops {

// The most bytes of patches a convolution stages at once: the size of the recorder's scratch
// it uses (Recorder::scratch; the memory estimate counts it, RequestShape::im2colScratchBytes).
constexpr int64_t kIm2colScratchBytes = int64_t(4) << 20;

// The bytes of scratch the device's convolutions stage their patches in: kIm2colScratchBytes
// where the plan has the lanes GEMM (KernelPlan::gemmLanesSplitK), 0 elsewhere.
uint64_t im2colScratchBytes(Engine& engine);

// An image [Cin, H, W] (element `first` of x on) and the band of output rows [oy0, oy0 + rows)
// of a KH x KW convolution with that stride and padding, Wo output columns.
struct Im2colBand {
  int64_t Cin, H, W, Wo, KH, KW;
  int stride = 1, padY = 0, padX = 0;
  int64_t oy0 = 0, rows = 0;
};

// p: [rows * Wo, Cin * KH * KW]; p[j][k] = x[ci][oy * stride - padY + ky][ox * stride - padX + kx]
// (0 outside the image) for output pixel j = (oy - oy0) * Wo + ox, k = (ci * KH + ky) * KW + kx.
// The image must fit one texel input binding.
void im2col(Recorder& rec, const Tensor& x, int64_t first, const Im2colBand& band, const Tensor& p);

}  // namespace spar::ops
