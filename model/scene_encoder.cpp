// Scene encoder (model/scene_encoder.h).
#include "model/scene_encoder.h"

#include "spar/error.h"
#include "engine/ops/copy2d.h"
#include "model/stack.h"

namespace spar {

SceneEncoder::SceneEncoder(Engine& engine, WeightSet& weights, const SparConfig& config)
    : engine_(engine), config_(config) {
  sceneCode_ = weights.require("scene_code", {config.sceneTokens, config.d}, DType::F32);
  options_ = TransformerBlockOptions::spar(config.d, config.dHead);
  options_.qkNorm = config.useQkNorm;
  blocks_ = loadStack(engine, weights, options_, "transformer_encoder_geom", config.sceneEncoderLayers);
}

void SceneEncoder::forward(Recorder& rec, const std::vector<Tensor>& parts, const Tensor& seq,
                           TransformerWorkspace& ws, const Tensor& input) {
  const int64_t d = config_.d, s = config_.sceneTokens;
  int64_t rows = s;
  for (const Tensor& p : parts) rows += p.numel() / d;
  if (seq.numel() != rows * d) throw Error("scene encoder: output " + seq.describe() + " should hold " +
                                           std::to_string(rows) + " tokens");
  copy2d(rec, sceneCode_, d, 0, seq, d, 0, s, d);
  int64_t at = s;
  for (const Tensor& p : parts) {
    const int64_t r = p.numel() / d;
    copy2d(rec, p, d, 0, seq.view(at * d, {r, d}), d, 0, r, d);
    at += r;
  }
  if (input.defined()) copy2d(rec, seq, d, 0, input, d, 0, rows, d);
  ws.reserve(engine_, rows, options_);
  forwardBlocks(rec, blocks_, seq.reshape({1, rows, d}), ws);
}

}  // namespace spar
