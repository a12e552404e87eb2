// Transposed convolution with kernel == stride (PyTorch nn.ConvTranspose2d(Cin, Cout, k, stride=k))
// on shaders/conv_transpose2d.comp.
#pragma once
#include "engine/ops/activation.h"
#include "engine/recorder.h"

namespace spar {

// x: [N, Cin, H, W], w: [Cin, Cout, k, k] (PyTorch's ConvTranspose2d layout), bias: [Cout]
// or undefined, y: [N, Cout, H*k, W*k]; all f32. No padding, no output padding:
// y[n][co][oy][ox] = act(bias[co] + sum_ci x[n][ci][oy/k][ox/k] * w[ci][co][oy%k][ox%k]).
void convTranspose2d(Recorder& rec, const Tensor& x, const Tensor& w, const Tensor& bias, const Tensor& y,
                     Activation act = Activation::None);

}  // namespace spar
