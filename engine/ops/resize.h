// Bilinear resize (PyTorch F.interpolate(mode='bilinear', antialias=False, size=...)) on
// shaders/resize.comp.
#pragma once
#include "engine/recorder.h"

namespace spar {

// x: [N, C, H, W] -> y: [N, C, Ho, Wo] (f32); the output size is y's shape. Up- and
// downsampling; downsampling does not antialias (as PyTorch's default).
void resizeBilinear(Recorder& rec, const Tensor& x, const Tensor& y, bool alignCorners);

}  // namespace spar
