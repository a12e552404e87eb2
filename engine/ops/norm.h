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

// The general form: for every row r and head h < heads, normalizes the dh values
// x[r, xCol0 + h * dh + j] into y[r, yCol0 + h * dh + j]. x: [rows..., Cx] and y: [rows..., Cy]
// with the same number of rows. weight: [dh] for every head, or [G, dh] for G groups of
// heads / G consecutive heads, each with its row (the q and the k part of a fused qkv tensor
// [T, 3D] in one dispatch: 2H heads at column 0, weight [q_norm; k_norm]). With y the same
// tensor as x and yCol0 == xCol0 it runs in place.
void rmsNormHeads(Recorder& rec, const Tensor& x, int64_t xCol0, const Tensor& y, int64_t yCol0, int64_t heads,
                  const Tensor& weight, float eps = 1e-6f);

}  // namespace spar
