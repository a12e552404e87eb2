// Softmax, L2 normalization and argmax along one axis (fp32) on shaders/reduce_channels.comp.
// The tensor is viewed as [outer, C, inner] around the axis: the last dimension of token
// rows (inner = 1) or the channels of NCHW maps (inner = H * W) alike.
#pragma once
#include "engine/recorder.h"

namespace spar {

// y = softmax(x) along `axis` (negative counts from the end), with the maximum subtracted.
// A line whose values are all -inf gives zeros. y: x's shape; may be x itself (in place).
void softmax(Recorder& rec, const Tensor& x, const Tensor& y, int axis = -1);

// y = x / max(||x||_2, eps) along `axis` (torch.nn.functional.normalize(x, dim=axis)); free
// of overflow for values up to FLT_MAX. y: x's shape; may be x itself (in place).
void l2Normalize(Recorder& rec, const Tensor& x, const Tensor& y, int axis, float eps = 1e-12f);

// index = torch.argmax(x, dim=axis) as int32: the first index of the maximum, NaN counting
// as the maximum. index: I32 with x's shape without `axis` (or with it as 1: keepdim).
void argmax(Recorder& rec, const Tensor& x, const Tensor& index, int axis);

}  // namespace spar
