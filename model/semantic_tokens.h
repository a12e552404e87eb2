// SPAR's semantic input tokens (reference: reference/spar_reference/spar.py SPAR.forward
// "semantic input tokens"): for each input view, the LSeg features at H/2 concatenated with the
// view's Plücker rays resized to H/2 (bilinear, align_corners false), average-pooled by 8 (one
// token per 16x16 pixels), then semantic_proj Linear(C + 6 -> D) + view_type_embedding[0].
// They are gated like the image tokens (model/gating.h) before the scene encoder.
#pragma once
#include <cstdint>
#include <vector>

#include "engine/engine.h"
#include "engine/recorder.h"
#include "model/spar_config.h"
#include "model/weight_set.h"

namespace spar {

class SemanticTokens {
 public:
  SemanticTokens(Engine& engine, WeightSet& weights, const SparConfig& config);

  // features [K, C, H/2, W/2] of the input views; rays [V, 6, H, W] of all views; inputs: the
  // input positions; tokens [K * (H/16) * (W/16), D] out. pooled (optional, tests): [K, C+6,
  // H/16, W/16] receives the pooled concatenation.
  void forward(Recorder& rec, const Tensor& features, const Tensor& rays, const std::vector<int64_t>& inputs,
               const Tensor& tokens, const Tensor& pooled = Tensor());

 private:
  Engine& engine_;
  const SparConfig& config_;
  Tensor projW_, projB_, viewType0_;
};

}  // namespace spar
