// SPAR's SAM2.1 refinement (model/sam2_refinement.h).
#include "model/sam2_refinement.h"

#include "spar/error.h"
#include "engine/ops/copy2d.h"
#include "engine/ops/resize.h"
#include "model/weight_set.h"

namespace spar {

WeightLookup sam2Weights(WeightSet& weights) {
  return [&weights](const std::string& name) -> Tensor {
    if (!weights.available(name)) return Tensor();
    const Shape& shape = weights.model().info(name).shape;
    return shape.size() == 4 ? weights.require(name, shape, DType::F32) : weights.require(name, shape);
  };
}

Sam2Refiner::Sam2Refiner(Engine& engine, const Sam2Config& config, const WeightLookup& weights,
                         const std::string& prefix)
    : engine_(engine), maskSide_(config.maskInputSize()), encoder_(engine, config, weights, prefix), decoder_(engine, config, weights, prefix) {}

Sam2Refined Sam2Refiner::refine(const Tensor& images, const Tensor& probs,
                                 const std::function<void(const Recorder&)>& ran) {
  if (!images.defined() || images.rank() != 4 || images.dim(1) != 3)
    throw Error("SAM2 refinement: images must be [V, 3, H, W]");
  if (!probs.defined() || probs.rank() != 3 || probs.dim(0) != images.dim(0) || probs.dim(1) != images.dim(2) ||
      probs.dim(2) != images.dim(3))
    throw Error("SAM2 refinement: probs " + probs.describe() + " do not match images " + images.describe());
  const int64_t V = probs.dim(0), H = probs.dim(1), W = probs.dim(2), side = maskSide_;

  // which views run: one readback of V counts; the binary masks are the skipped views' output
  const Tensor counts = engine_.tensor({V}, DType::I32);
  const Tensor binary = engine_.tensor({V, H, W});
  const bool profile = bool(ran);
  const auto submit = [&](Recorder& rec) {
    rec.run();
    if (ran) ran(rec);
  };
  {
    Recorder rec(engine_, profile);
    rec.setStage("sam2_refine");
    sam2CountDynamic(rec, probs, counts);
    sam2Threshold(rec, probs, 0.5f, binary);
    submit(rec);
  }
  std::vector<int32_t> count(static_cast<size_t>(V));
  engine_.read(counts, count.data(), count.size() * sizeof(int32_t));

  Sam2Refined out;
  out.masks = engine_.download(binary);
  out.views.resize(size_t(V));
  for (int64_t v = 0; v < V; ++v) {
    Sam2ViewRefinement& r = out.views[size_t(v)];
    r.dynamicPixels = count[size_t(v)];
    r.skipped = r.dynamicPixels < kSkipMin || r.dynamicPixels > H * W - kSkipMin;
    if (r.skipped) continue;
    Recorder rec(engine_, profile);
    rec.setStage("sam2_refine");
    const Sam2ImageFeatures f = encoder_.encode(rec, images, v, submit);  // one block's maps at a time
    const Sam2MaskResult m = decoder_.decode(rec, f, probs, v);
    Tensor full = m.chosenLogits.reshape({1, 1, side, side});
    if (H != side || W != side) {
      full = engine_.tensor({1, 1, H, W});
      resizeBilinear(rec, m.chosenLogits.reshape({1, 1, side, side}), full, false);
    }
    const Tensor refined = engine_.tensor({H * W});
    sam2Threshold(rec, full, 0.0f, refined);
    submit(rec);
    const std::vector<float> iou = engine_.download(m.iou);
    for (int i = 0; i < 3; ++i) r.iou[size_t(i)] = iou[size_t(i)];
    r.chosen = 0;  // numpy's argmax: the first of equal maxima (as the kernel's strict >)
    for (int i = 1; i < 3; ++i)
      if (r.iou[size_t(i)] > r.iou[size_t(r.chosen)]) r.chosen = i;
    r.logits = engine_.download(m.chosenLogits);
    const std::vector<float> mask = engine_.download(refined);
    std::copy(mask.begin(), mask.end(), out.masks.begin() + v * H * W);
  }
  return out;
}

}  // namespace spar
