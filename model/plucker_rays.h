// Plücker ray maps of pinhole cameras on the engine (kernel: model/shaders/plucker_rays.comp;
// reference: reference/spar_reference/spar.py plucker_rays).
//
//   c2w       [V, 4, 4] f32, camera-to-world, OpenCV frame (+z forward), [R | t] row-major
//   fxfycxcy  [V, 4]    f32, intrinsics divided by the image size (fx, cx by W; fy, cy by H)
//   rays      [V, 6, H, W] f32, channels [o x d, d]: o = t, d the unit direction through the
//             pixel centre (x + 0.5, y + 0.5), d = normalize(R [(x+0.5-cx)/fx, (y+0.5-cy)/fy, 1])
//
// Leading dimensions may be any [B, V] that multiply to V (e.g. rays [B, V, 6, H, W]).
// Recorded into the caller's Recorder; nothing runs on the CPU.
#pragma once
#include "engine/engine.h"
#include "engine/recorder.h"

namespace spar {

void pluckerRays(Recorder& rec, const Tensor& c2w, const Tensor& fxfycxcy, const Tensor& rays);

}  // namespace spar
