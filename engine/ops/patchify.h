// Patchify / unpatchify between NCHW images and patch tokens on shaders/patchify.comp.
#pragma once
#include "engine/recorder.h"

namespace spar {

// images: [V, C, H, W] -> tokens: [V, (H/p)*(W/p), p*p*C], features in (ph pw c) order
// (einops "b c (hh ph) (ww pw) -> b (hh ww) (ph pw c)"). H and W must be multiples of p.
void patchify(Recorder& rec, const Tensor& images, const Tensor& tokens, int p);

// The inverse: tokens [V, (H/p)*(W/p), p*p*C] -> images [V, C, H, W] (sizes from images).
void unpatchify(Recorder& rec, const Tensor& tokens, const Tensor& images, int p);

}  // namespace spar
