// Cameras from the pose estimator's head outputs, on the engine (kernel: model/shaders/pose_head.comp;
// reference: reference/spar_reference/spar.py PoseEstimator.forward, cam_info_to_se3 and
// rot6d_to_mat with reorthogonalize=True).
//
//   rel       [B, V-1, 9] f32: rel_head outputs of the non-canonical views, in view order,
//             raw (the identity offset [1,0,0, 0,1,0 | 0,0,0] is added by the kernel)
//   kraw      [B] or [B, 1] f32: canonical_k_head output, raw (+ 1.25 added by the kernel)
//   c2w       [B, V, 4, 4] f32 out: R = [b1 b2 b1xb2] (6D Gram-Schmidt), t; the canonical view
//             is the identity
//   fxfycxcy  [B, V, 4] f32 out: (f, f, 0.5, 0.5), f = kraw + 1.25, normalized intrinsics
//   canonical index of the canonical view: V / 2 (cfg.canonical 'middle', SPAR) or 0 ('first')
//
// With V = 1, rel may be undefined (no relative views). Recorded into the caller's Recorder.
#pragma once
#include <cstdint>

#include "engine/engine.h"
#include "engine/recorder.h"

namespace spar {

void poseHead(Recorder& rec, const Tensor& rel, const Tensor& kraw, const Tensor& c2w, const Tensor& fxfycxcy,
              int64_t canonical);

// SPAR's canonical view: the middle one.
inline int64_t middleCanonical(int64_t views) { return views / 2; }

}  // namespace spar
