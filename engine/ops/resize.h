// Bilinear resize (PyTorch F.interpolate(mode='bilinear', antialias=False, size=...)) on
// shaders/resize.comp.
#pragma once
#include "engine/recorder.h"

namespace spar {

// x: [N, C, H, W] -> y: [N, C, Ho, Wo] (f32); the output size is y's shape. Up- and
// downsampling; downsampling does not antialias (as PyTorch's default).
void resizeBilinear(Recorder& rec, const Tensor& x, const Tensor& y, bool alignCorners);

// scores: [N, C, H, W] f32 -> maps: [N, Ho, Wo] i32, the index of the first largest channel of
// resizeBilinear(scores) at each output pixel (torch.argmax(F.interpolate(...), dim=1)), in one
// pass that never stores the resized scores: LSeg's full-resolution label map from its logits.
void resizeBilinearArgmax(Recorder& rec, const Tensor& scores, const Tensor& maps, bool alignCorners);

}  // namespace spar
