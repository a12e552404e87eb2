// The scene encoder (transformer_encoder_geom; reference: reference/spar_reference/spar.py
// SPAR.forward "scene encoder"): over [scene_code (S learned tokens), gated image tokens of the
// input views, gated semantic tokens (semantic models)], keeping the first S outputs as the
// scene representation the decoder attends to.
#pragma once
#include <cstdint>
#include <vector>

#include "engine/engine.h"
#include "engine/recorder.h"
#include "model/spar_config.h"
#include "model/transformer_block.h"
#include "model/weight_set.h"

namespace spar {

class SceneEncoder {
 public:
  SceneEncoder(Engine& engine, WeightSet& weights, const SparConfig& config);

  // parts: the token groups after the scene code ([K*n, D] gated image tokens, then the semantic
  // tokens if any); seq: [S + sum(rows), D] out (the encoder's whole output; its first S rows are
  // the scene tokens). `input` (optional, tests): receives the encoder input.
  void forward(Recorder& rec, const std::vector<Tensor>& parts, const Tensor& seq, TransformerWorkspace& ws,
               const Tensor& input = Tensor());
  int64_t sceneTokens() const { return config_.sceneTokens; }

 private:
  Engine& engine_;
  const SparConfig& config_;
  Tensor sceneCode_;
  TransformerBlockOptions options_;
  std::vector<TransformerBlock> blocks_;
};

}  // namespace spar
