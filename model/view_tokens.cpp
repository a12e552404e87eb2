// View tokenizers (model/view_tokens.h).
#include "model/view_tokens.h"

#include "engine/ops/binary.h"
#include "engine/ops/copy2d.h"
#include "engine/ops/linear.h"
#include "engine/ops/patchify.h"
#include "engine/ops/unary.h"
#include "model/sincos_codes.h"

namespace spar {
namespace {

// Linear(D, D) -> SiLU -> Linear(D, D) with biases, x [R, D] -> y [R, D] through hidden [R, D].
void embedder(Recorder& rec, WeightSet& w, const std::string& prefix, int64_t d, const Tensor& x,
              const Tensor& hidden, const Tensor& y) {
  linear(rec, x, w.require(prefix + ".0.weight", {d, d}), w.require(prefix + ".0.bias", {d}, DType::F32), hidden,
         Activation::Silu);
  linear(rec, hidden, w.require(prefix + ".2.weight", {d, d}), w.require(prefix + ".2.bias", {d}, DType::F32), y);
}

}  // namespace

ViewTokenizer::ViewTokenizer(Engine& engine, WeightSet& weights, const SparConfig& config)
    : engine_(engine), weights_(weights), config_(config) {}

const Tensor& ViewTokenizer::imageCode(int64_t views, int64_t gh, int64_t gw) {
  auto key = std::make_pair(views, std::make_pair(gh, gw));
  auto it = imageCodes_.find(key);
  if (it == imageCodes_.end()) {
    const std::vector<float> code = imageTokenCode(config_.d, gh, gw, views);
    it = imageCodes_.emplace(key, engine_.fromFloats({views, gh * gw, config_.d}, code)).first;
  }
  return it->second;
}

const Tensor& ViewTokenizer::cameraCode(int64_t views) {
  auto it = cameraCodes_.find(views);
  if (it == cameraCodes_.end())
    it = cameraCodes_.emplace(views, engine_.fromFloats({views, config_.d}, cameraTokenCode(config_.d, views))).first;
  return it->second;
}

void ViewTokenizer::imageTokens(Recorder& rec, const Tensor& images, const Tensor& raw, const Tensor& tokens,
                                const Tensor& code) {
  const int64_t v = images.dim(0), h = images.dim(2), w = images.dim(3), p = config_.patchSize, d = config_.d;
  const int64_t gh = h / p, gw = w / p, n = gh * gw;
  // 2 * img - 1, patchified, through image_tokenizer.1 (no bias).
  const Tensor scaled = engine_.tensor(images.shape());
  scale(rec, images, scaled, 2.0f, -1.0f);
  const Tensor patches = engine_.tensor({v, n, p * p * 3});
  patchify(rec, scaled, patches, int(p));
  linear(rec, patches, weights_.require("image_tokenizer.1.weight", {d, p * p * 3}), Tensor(), raw);
  // + pe_embedder(code): the embedder output is computed for the codes of all V views.
  const Tensor& c = imageCode(v, gh, gw);
  if (code.defined()) copy2d(rec, c, d, 0, code, d, 0, v * n, d);
  const Tensor hidden = engine_.tensor({v * n, d});
  embedder(rec, weights_, "pe_embedder", d, c.reshape({v * n, d}), hidden, tokens.reshape({v * n, d}));
  add(rec, tokens, raw, tokens);
}

void ViewTokenizer::cameraTokens(Recorder& rec, int64_t views, const Tensor& out) {
  const int64_t d = config_.d;
  const Tensor hidden = engine_.tensor({views, d});
  embedder(rec, weights_, "temporal_pe_embedder", d, cameraCode(views), hidden, out);
  const Tensor& cam = weights_.require("cam_code", {1, d}, DType::F32);
  add(rec, out, cam.reshape({d}), out);
}

void ViewTokenizer::rayTokens(Recorder& rec, const std::string& name, const Tensor& rays, const Tensor& out) {
  const int64_t v = rays.dim(0), h = rays.dim(2), w = rays.dim(3), p = config_.patchSize, d = config_.d;
  const int64_t n = (h / p) * (w / p);
  const Tensor patches = engine_.tensor({v, n, p * p * 6});
  patchify(rec, rays, patches, int(p));
  linear(rec, patches, weights_.require(name + ".1.weight", {d, p * p * 6}), Tensor(), out);
}

}  // namespace spar
