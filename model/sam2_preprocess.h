// SAM2.1's image pre-processing on the engine (kernel: model/shaders/sam2_preprocess.comp;
// reference: reference/spar_reference/sam2.py preprocess).
//
//   images [V, 3, H, W] f32 in [0, 1], the engine's input images; view: which one
//   out    [3, S, S] f32 (SAM2.1: S = 1024): SPAR's uint8 cast (x 255, truncated), bilinear
//          resize (PyTorch's align_corners=False), ImageNet normalisation
//
// An upsampling only (S >= H and S >= W): the official torchvision Resize antialiases when it
// shrinks, which this kernel does not do, so a larger image is refused rather than resized
// differently.
#pragma once
#include "engine/engine.h"
#include "engine/recorder.h"

namespace spar {

void sam2Preprocess(Recorder& rec, const Tensor& images, int64_t view, const Tensor& out);

}  // namespace spar
