// LayerNorm and RMSNorm (fp32) on shaders/norm.comp.
#pragma once
#include "engine/recorder.h"

namespace spar {

// y = (x - mean) / sqrt(var + eps) * weight + bias over the last dimension (nn.LayerNorm).
// x, y: [..., D] f32 of the same shape; weight, bias: [D] or undefined (LayerNorm without
// affine, or bias=False). y may be x itself (in place).
void layerNorm(Recorder& rec, const Tensor& x, const Tensor& weight, const Tensor& bias, const Tensor& y,
               float eps = 1e-5f);

// y = x / sqrt(mean(x^2) + eps) * weight over every group of dh = weight.numel() consecutive
// values of the last dimension (per-head RMSNorm when D = heads * dh, nn.RMSNorm when dh = D).
// x, y: [..., D] f32 of the same shape; y may be x itself (in place).
void rmsNorm(Recorder& rec, const Tensor& x, const Tensor& weight, const Tensor& y, float eps = 1e-6f);

// The general form: for every row r and head h < heads, normalizes the dh = weight.numel()
// values x[r, xCol0 + h * dh + j] into y[r, yCol0 + h * dh + j]. x: [rows..., Cx] and
// y: [rows..., Cy] with the same number of rows. With y the same tensor as x and
// yCol0 == xCol0 it runs in place, e.g. on the q part (xCol0 0) or k part (xCol0 D) of a
// fused qkv tensor [T, 3D].
void rmsNormHeads(Recorder& rec, const Tensor& x, int64_t xCol0, const Tensor& y, int64_t yCol0, int64_t heads,
                  const Tensor& weight, float eps = 1e-6f);

}  // namespace spar
