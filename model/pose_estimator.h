// RayZer's pose estimator as SPAR runs it (reference: reference/spar_reference/spar.py
// SPAR.forward "pose encoder" and PoseEstimator): the pose encoder (transformer_encoder) over
// [one camera token per view, the image tokens of all views], then on the camera tokens
//   rel_head        Linear(2D, D) -> SiLU -> Linear(D, 9) on concat(canonical token, view token)
//   canonical_k_head Linear(D, D) -> SiLU -> Linear(D, 1) on the canonical token
// and the cameras from them (model/pose_head.h: 6D rotation, t, shared focal + 1.25).
#pragma once
#include <cstdint>
#include <vector>

#include "engine/engine.h"
#include "engine/recorder.h"
#include "model/spar_config.h"
#include "model/transformer_block.h"
#include "model/weight_set.h"

namespace spar {

class PoseEstimator {
 public:
  PoseEstimator(Engine& engine, WeightSet& weights, const SparConfig& config);

  // cam [V, D], img [V, n, D] -> enc [V + V*n, D] (pose encoder output; its first V rows are the
  // camera tokens), c2w [V, 4, 4], fxfycxcy [V, 4]. ws is reserved here as needed.
  void forward(Recorder& rec, const Tensor& cam, const Tensor& img, const Tensor& enc, const Tensor& c2w,
               const Tensor& fxfycxcy, TransformerWorkspace& ws);

 private:
  Engine& engine_;
  WeightSet& weights_;
  const SparConfig& config_;
  TransformerBlockOptions options_;
  std::vector<TransformerBlock> blocks_;
};

}  // namespace spar
