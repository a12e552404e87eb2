// Renderer (model/renderer.h).
#include "model/renderer.h"

#include <algorithm>

#include "engine/ops/binary.h"
#include "engine/ops/copy2d.h"
#include "engine/ops/linear.h"
#include "engine/ops/norm.h"
#include "engine/ops/patchify.h"
#include "model/stack.h"

namespace spar {

Renderer::Renderer(Engine& engine, WeightSet& weights, const SparConfig& config, ViewTokenizer& tokenizer)
    : engine_(engine), weights_(weights), config_(config), tokenizer_(tokenizer) {
  const int64_t d = config.d, p = config.patchSize;
  options_ = TransformerBlockOptions::spar(d, config.dHead);
  options_.qkNorm = config.useQkNorm;
  blocks_ = loadStack(engine, weights, options_, "transformer_decoder", config.decoderLayers);
  lnW_ = weights.require("decoder_ln.weight", {d}, DType::F32);
  viewType1_ = weights.require("view_type_embedding.weight", {2, d}, DType::F32).view(d, {d});
  headLnW_ = weights.require("image_token_decoder.0.weight", {d}, DType::F32);
  headW_ = weights.require("image_token_decoder.1.weight", {p * p * 3, d});
}

void Renderer::forward(Recorder& rec, const Tensor& rays, const Tensor& scene, const Tensor& rgb,
                       TransformerWorkspace& ws, RenderTrace* trace) {
  const int64_t r = rays.dim(0), h = rays.dim(2), w = rays.dim(3);
  if (trace || r <= kViewsPerBatch) return batch(rec, rays, scene, rgb, ws, trace);
  for (int64_t v0 = 0; v0 < r; v0 += kViewsPerBatch) {
    const int64_t m = std::min(kViewsPerBatch, r - v0);
    batch(rec, rays.view(v0 * 6 * h * w, {m, 6, h, w}), scene, rgb.view(v0 * 3 * h * w, {m, 3, h, w}), ws, nullptr);
  }
}

void Renderer::batch(Recorder& rec, const Tensor& rays, const Tensor& scene, const Tensor& rgb,
                     TransformerWorkspace& ws, RenderTrace* trace) {
  const int64_t r = rays.dim(0), d = config_.d, p = config_.patchSize, s = config_.sceneTokens;
  const int64_t n = (rays.dim(2) / p) * (rays.dim(3) / p), len = n + s;
  // RGB queries
  const Tensor queries = engine_.tensor({r, n, d});
  tokenizer_.rayTokens(rec, "target_pose_tokenizer2", rays, queries);
  add(rec, queries, viewType1_, queries);
  // decoder_ln([queries, scene tokens]) per view
  const Tensor seq = engine_.tensor({r, len, d});
  for (int64_t v = 0; v < r; ++v) {
    copy2d(rec, queries.view(v * n * d, {n, d}), d, 0, seq.view(v * len * d, {n, d}), d, 0, n, d);
    copy2d(rec, scene, d, 0, seq.view((v * len + n) * d, {s, d}), d, 0, s, d);
  }
  layerNorm(rec, seq, lnW_, Tensor(), seq, 1e-5f);
  if (trace) {
    trace->rgbQueries = queries;
    trace->decoderIn = engine_.tensor({r, len, d});
    copy2d(rec, seq, d, 0, trace->decoderIn, d, 0, r * len, d);
  }
  ws.reserve(engine_, r * len, options_);
  forwardBlocks(rec, blocks_, seq, ws);
  // RGB head on the first n tokens of each view
  const Tensor tokens = engine_.tensor({r, n, d});
  slice(rec, seq, 1, 0, n, tokens);
  if (trace) {
    trace->decoderOut = seq;
    trace->rgbTokens = engine_.tensor({r, n, d});
    copy2d(rec, tokens, d, 0, trace->rgbTokens, d, 0, r * n, d);
  }
  layerNorm(rec, tokens, headLnW_, Tensor(), tokens, 1e-5f);
  const Tensor patches = engine_.tensor({r, n, p * p * 3});
  linear(rec, tokens, headW_, Tensor(), patches, Activation::Sigmoid);
  unpatchify(rec, patches, rgb, int(p));
}

}  // namespace spar
