// Renderer (model/renderer.h).
#include "model/renderer.h"

#include <algorithm>

#include "spar/error.h"
#include "engine/ops/binary.h"
#include "engine/ops/conv2d.h"
#include "engine/ops/copy2d.h"
#include "engine/ops/linear.h"
#include "engine/ops/norm.h"
#include "engine/ops/patchify.h"
#include "engine/ops/resize.h"
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
  semanticQueries_ = config.semanticDecoding();
}

void Renderer::forward(Recorder& rec, const Tensor& rays, const Tensor& scene, const Tensor& rgb,
                       TransformerWorkspace& ws, const Tensor& features, RenderTrace* trace) {
  if (features.defined() && !semanticQueries_)
    throw Error("renderer: this model has no semantic decoding, so no semantic features");
  const int64_t r = rays.dim(0), h = rays.dim(2), w = rays.dim(3);
  if (trace || r <= kViewsPerBatch) return batch(rec, rays, scene, rgb, ws, features, trace);
  const int64_t c = config_.semanticDim, fhw = (h / 2) * (w / 2);
  for (int64_t v0 = 0; v0 < r; v0 += kViewsPerBatch) {
    const int64_t m = std::min(kViewsPerBatch, r - v0);
    batch(rec, rays.view(v0 * 6 * h * w, {m, 6, h, w}), scene, rgb.view(v0 * 3 * h * w, {m, 3, h, w}), ws,
          features.defined() ? features.view(v0 * c * fhw, {m, c, h / 2, w / 2}) : Tensor(), nullptr);
  }
}

void Renderer::batch(Recorder& rec, const Tensor& rays, const Tensor& scene, const Tensor& rgb,
                     TransformerWorkspace& ws, const Tensor& features, RenderTrace* trace) {
  const int64_t r = rays.dim(0), d = config_.d, p = config_.patchSize, s = config_.sceneTokens;
  const int64_t n = (rays.dim(2) / p) * (rays.dim(3) / p);
  const int64_t q = semanticQueries_ ? 2 * n : n, len = q + s;
  // Ray queries: RGB, then semantic.
  const Tensor queries = engine_.tensor({r, n, d});
  tokenizer_.rayTokens(rec, "target_pose_tokenizer2", rays, queries);
  add(rec, queries, viewType1_, queries);
  Tensor semQueries;
  if (semanticQueries_) {
    semQueries = engine_.tensor({r, n, d});
    tokenizer_.rayTokens(rec, "target_pose_tokenizer_semantic", rays, semQueries);
    add(rec, semQueries, viewType1_, semQueries);
  }
  // decoder_ln([queries, scene tokens]) per view
  const Tensor seq = engine_.tensor({r, len, d});
  for (int64_t v = 0; v < r; ++v) {
    copy2d(rec, queries.view(v * n * d, {n, d}), d, 0, seq.view(v * len * d, {n, d}), d, 0, n, d);
    if (semQueries.defined())
      copy2d(rec, semQueries.view(v * n * d, {n, d}), d, 0, seq.view((v * len + n) * d, {n, d}), d, 0, n, d);
    copy2d(rec, scene, d, 0, seq.view((v * len + q) * d, {s, d}), d, 0, s, d);
  }
  layerNorm(rec, seq, lnW_, Tensor(), seq, 1e-5f);
  if (trace) {
    trace->rgbQueries = queries;
    trace->semanticQueries = semQueries;
    trace->decoderIn = engine_.tensor({r, len, d});
    copy2d(rec, seq, d, 0, trace->decoderIn, d, 0, r * len, d);
  }
  ws.reserve(engine_, r * len, options_);
  forwardBlocks(rec, blocks_, seq, ws);
  if (trace) trace->decoderOut = seq;
  // RGB head on the first n tokens of each view
  const Tensor tokens = engine_.tensor({r, n, d});
  slice(rec, seq, 1, 0, n, tokens);
  if (trace) {
    trace->rgbTokens = engine_.tensor({r, n, d});
    copy2d(rec, tokens, d, 0, trace->rgbTokens, d, 0, r * n, d);
  }
  layerNorm(rec, tokens, headLnW_, Tensor(), tokens, 1e-5f);
  const Tensor patches = engine_.tensor({r, n, p * p * 3});
  linear(rec, tokens, headW_, Tensor(), patches, Activation::Sigmoid);
  unpatchify(rec, patches, rgb, int(p));
  // Semantic head on the next n tokens, only when features are asked for.
  if (features.defined()) {
    const Tensor semTokens = engine_.tensor({r, n, d});
    slice(rec, seq, 1, n, n, semTokens);
    if (trace) {
      trace->semanticOutTokens = engine_.tensor({r, n, d});
      copy2d(rec, semTokens, d, 0, trace->semanticOutTokens, d, 0, r * n, d);
    }
    semanticHead(rec, semTokens, features, trace);
  }
}

void Renderer::semanticHead(Recorder& rec, const Tensor& tokens, const Tensor& features, RenderTrace* trace) {
  const int64_t r = tokens.dim(0), n = tokens.dim(1), d = config_.d, p = config_.patchSize;
  const int64_t hid = config_.semanticHidden, c = config_.semanticDim;
  const int64_t h2 = features.dim(2), w2 = features.dim(3), h = 2 * h2, w = 2 * w2;
  const std::string pre = "semantic_token_decoder.";
  WeightSet& wt = weights_;
  layerNorm(rec, tokens, wt.require(pre + "0.weight", {d}, DType::F32), Tensor(), tokens, 1e-5f);
  const Tensor a = engine_.tensor({r, n, 2 * d}), b = engine_.tensor({r, n, 4 * d});
  linear(rec, tokens, wt.require(pre + "1.weight", {2 * d, d}), Tensor(), a, Activation::Gelu);
  linear(rec, a, wt.require(pre + "3.weight", {4 * d, 2 * d}), Tensor(), b, Activation::Gelu);
  const Tensor patches = engine_.tensor({r, n, p * p * hid});
  linear(rec, b, wt.require(pre + "5.weight", {p * p * hid, 4 * d}), Tensor(), patches);
  const Tensor hidden = engine_.tensor({r, hid, h, w});
  unpatchify(rec, patches, hidden, int(p));
  if (trace) trace->semanticHidden = hidden;
  // semantic_feature_expansion: bilinear x0.5 (align_corners false), Conv1x1 hid -> C with bias.
  const Tensor half = engine_.tensor({r, hid, h2, w2});
  resizeBilinear(rec, hidden, half, false);
  // conv2d reads f32 kernels (an fp16 pack is converted at upload).
  conv2d(rec, half, wt.require("semantic_feature_expansion.1.weight", {c, hid, 1, 1}, DType::F32),
         wt.require("semantic_feature_expansion.1.bias", {c}, DType::F32), features, Conv2dParams{});
}

}  // namespace spar
