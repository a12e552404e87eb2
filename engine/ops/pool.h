// Average pooling (PyTorch nn.AvgPool2d(k)) on shaders/pool.comp.
#pragma once
#include "engine/recorder.h"

namespace spar {

// x: [N, C, H, W] -> y: [N, C, H / k, W / k] (floor; f32): the mean of each k x k window,
// stride k, no padding.
void avgPool2d(Recorder& rec, const Tensor& x, const Tensor& y, int k);

}  // namespace spar
