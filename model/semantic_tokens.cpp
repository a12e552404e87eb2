// Semantic input tokens (model/semantic_tokens.h).
#include "model/semantic_tokens.h"

#include "spar/error.h"
#include "engine/ops/binary.h"
#include "engine/ops/copy2d.h"
#include "engine/ops/linear.h"
#include "engine/ops/patchify.h"
#include "engine/ops/pool.h"
#include "engine/ops/resize.h"

namespace spar {

SemanticTokens::SemanticTokens(Engine& engine, WeightSet& weights, const SparConfig& config)
    : engine_(engine), config_(config) {
  const int64_t d = config.d, c = config.semanticDim;
  projW_ = weights.require("semantic_proj.weight", {d, c + 6});
  projB_ = weights.require("semantic_proj.bias", {d}, DType::F32);
  viewType0_ = weights.require("view_type_embedding.weight", {2, d}, DType::F32).view(0, {d});
}

void SemanticTokens::forward(Recorder& rec, const Tensor& features, const Tensor& rays,
                             const std::vector<int64_t>& inputs, const Tensor& tokens, const Tensor& pooled) {
  const int64_t k = int64_t(inputs.size()), c = config_.semanticDim, d = config_.d;
  const int64_t h = rays.dim(2), w = rays.dim(3), h2 = h / 2, w2 = w / 2, hs = h / 16, ws = w / 16;
  if (features.rank() != 4 || features.dim(0) != k || features.dim(1) != c || features.dim(2) != h2 ||
      features.dim(3) != w2)
    throw Error("semantic tokens: features " + features.describe() + " should be [" + std::to_string(k) + ", " +
                std::to_string(c) + ", " + std::to_string(h2) + ", " + std::to_string(w2) + "]");
  // concat(features, rays at H/2) per input view, channels first.
  const int64_t hw2 = h2 * w2;
  const Tensor cat = engine_.tensor({k, c + 6, h2, w2});
  copy2d(rec, features, c * hw2, 0, cat, (c + 6) * hw2, 0, k, c * hw2);
  for (int64_t j = 0; j < k; ++j)
    resizeBilinear(rec, rays.view(inputs[j] * 6 * h * w, {1, 6, h, w}),
                   cat.view((j * (c + 6) + c) * hw2, {1, 6, h2, w2}), false);
  // AvgPool2d(8): one value per 16x16 pixels of the full image.
  const Tensor pool = pooled.defined() ? pooled : engine_.tensor({k, c + 6, hs, ws});
  avgPool2d(rec, cat, pool, 8);
  // channels-first -> token rows (patchify with p = 1 is exactly that transpose), projection.
  const Tensor rows = engine_.tensor({k, hs * ws, c + 6});
  patchify(rec, pool, rows, 1);
  linear(rec, rows, projW_, projB_, tokens.reshape({k, hs * ws, d}));
  add(rec, tokens, viewType0_, tokens);
}

}  // namespace spar
