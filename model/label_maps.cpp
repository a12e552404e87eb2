#include "model/label_maps.h"

#include "spar/error.h"
#include "engine/ops/conv2d.h"
#include "engine/ops/reduce_channels.h"
#include "engine/ops/resize.h"
#include "engine/ops/unary.h"

namespace spar {

void labelLogits(Recorder& rec, const Tensor& features, const Tensor& text, const Tensor& logits, float logitScale) {
  Engine& engine = rec.engine();
  if (!features.defined() || features.rank() != 4 || features.dtype() != DType::F32)
    throw Error("label maps: features must be f32 [R, C, h, w], got " +
                (features.defined() ? features.describe() : std::string("(none)")));
  const int64_t R = features.dim(0), C = features.dim(1), h = features.dim(2), w = features.dim(3);
  if (!text.defined() || text.rank() != 2 || text.dim(1) != C || text.dtype() != DType::F32)
    throw Error("label maps: text embeddings must be f32 [P, " + std::to_string(C) + "], got " +
                (text.defined() ? text.describe() : std::string("(none)")));
  const int64_t P = text.dim(0);
  if (!logits.defined() || logits.shape() != Shape{R, P, h, w} || logits.dtype() != DType::F32)
    throw Error("label maps: logits must be f32 " + shapeString({R, P, h, w}) + ", got " +
                (logits.defined() ? logits.describe() : std::string("(none)")));
  if (logits.numel() == 0) return;

  const Tensor img = engine.tensor(features.shape());
  const Tensor txt = engine.tensor({P, C, 1, 1});
  l2Normalize(rec, features, img, 1);
  l2Normalize(rec, text, txt.reshape({P, C}), 1);
  conv2d(rec, img, txt, Tensor(), logits);  // logits[r, p] = sum_c img[r, c] * txt[p, c]
  scale(rec, logits, logits, logitScale);      // after the sum, as the reference orders it
}

void labelMaps(Recorder& rec, const Tensor& features, const Tensor& text, const Tensor& maps, const Tensor& logits,
               float logitScale) {
  if (!features.defined() || features.rank() != 4 || !text.defined() || text.rank() != 2)
    throw Error("label maps: features must be [R, C, h, w] and text [P, C]");
  const int64_t R = features.dim(0), h = features.dim(2), w = features.dim(3), P = text.dim(0);
  if (!maps.defined() || maps.shape() != Shape{R, 2 * h, 2 * w} || maps.dtype() != DType::I32)
    throw Error("label maps: maps must be i32 " + shapeString({R, 2 * h, 2 * w}) + ", got " +
                (maps.defined() ? maps.describe() : std::string("(none)")));
  if (P == 0) throw Error("label maps: no prompts");
  const Tensor scores = logits.defined() ? logits : rec.engine().tensor({R, P, h, w});
  labelLogits(rec, features, text, scores, logitScale);
  resizeBilinearArgmax(rec, scores, maps, /*alignCorners=*/true);
}

}  // namespace spar
