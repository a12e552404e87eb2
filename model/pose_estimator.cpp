// Pose estimator (model/pose_estimator.h).
#include "model/pose_estimator.h"

#include "engine/ops/copy2d.h"
#include "engine/ops/linear.h"
#include "model/pose_head.h"
#include "model/stack.h"

namespace spar {

PoseEstimator::PoseEstimator(Engine& engine, WeightSet& weights, const SparConfig& config)
    : engine_(engine), weights_(weights), config_(config) {
  options_ = TransformerBlockOptions::spar(config.d, config.dHead);
  options_.qkNorm = config.useQkNorm;
  blocks_ = loadStack(engine, weights, options_, "transformer_encoder", config.encoderLayers);
}

void PoseEstimator::forward(Recorder& rec, const Tensor& cam, const Tensor& img, const Tensor& enc,
                            const Tensor& c2w, const Tensor& fxfycxcy, TransformerWorkspace& ws) {
  const int64_t d = config_.d, v = cam.dim(0), n = img.dim(1), rows = v + v * n;
  // [camera tokens, image tokens] -> pose encoder
  copy2d(rec, cam, d, 0, enc, d, 0, v, d);
  copy2d(rec, img, d, 0, enc.view(v * d, {v * n, d}), d, 0, v * n, d);
  ws.reserve(engine_, rows, options_);
  forwardBlocks(rec, blocks_, enc.reshape({1, rows, d}), ws);

  const int64_t ci = config_.canonicalIndex(v);
  const Tensor camOut = enc.view(0, {v, d});
  const Tensor canonical = enc.view(ci * d, {1, d});
  const std::string p = "pose_predictor.";
  // canonical_k_head -> raw focal (the kernel adds 1.25)
  const Tensor kHidden = engine_.tensor({1, d}), kRaw = engine_.tensor({1, 1});
  linear(rec, canonical, weights_.require(p + "canonical_k_head.0.weight", {d, d}),
         weights_.require(p + "canonical_k_head.0.bias", {d}, DType::F32), kHidden, Activation::Silu);
  linear(rec, kHidden, weights_.require(p + "canonical_k_head.2.weight", {1, d}),
         weights_.require(p + "canonical_k_head.2.bias", {1}, DType::F32), kRaw);
  // rel_head on concat(canonical token, view token) of every other view, in view order
  Tensor rel;
  if (v > 1) {
    const Tensor pairs = engine_.tensor({v - 1, 2 * d}), hidden = engine_.tensor({v - 1, d});
    rel = engine_.tensor({1, v - 1, 9});
    for (int64_t i = 0, row = 0; i < v; ++i) {
      if (i == ci) continue;
      copy2d(rec, canonical, d, 0, pairs.view(row * 2 * d, {1, 2 * d}), 2 * d, 0, 1, d);
      copy2d(rec, camOut.view(i * d, {1, d}), d, 0, pairs.view(row * 2 * d, {1, 2 * d}), 2 * d, d, 1, d);
      ++row;
    }
    linear(rec, pairs, weights_.require(p + "rel_head.0.weight", {d, 2 * d}),
           weights_.require(p + "rel_head.0.bias", {d}, DType::F32), hidden, Activation::Silu);
    linear(rec, hidden, weights_.require(p + "rel_head.2.weight", {9, d}),
           weights_.require(p + "rel_head.2.bias", {9}, DType::F32), rel.reshape({v - 1, 9}));
  }
  poseHead(rec, rel, kRaw.reshape({1}), c2w.reshape({1, v, 4, 4}), fxfycxcy.reshape({1, v, 4}), ci);
}

}  // namespace spar
