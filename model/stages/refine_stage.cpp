// SAM2.1's refinement of the motion masks (model/stages/stages.h; only when asked: no SAM2
// weight is uploaded otherwise): each input's mask (and each target's with targetMotion),
// prompted by CV-DRP's P(dynamic) or the request's own masks, on the views' captured images (the
// official _sam2_refine_masks: real target frames, not renders), view by view
// (model/sam2_refinement.h). It submits its own work, one submission a view's part.
#include <algorithm>
#include <chrono>

#include "model/sam2_config.h"
#include "model/stage_models.h"
#include "model/stages/select_views.h"
#include "model/stages/stages.h"

namespace spar::stages {
namespace {

// What SAM2.1's refinement of one view holds at once at least (for the lower bound): the larger
// of two moments. During the first Hiera block: the 1024x1024 input, the patch embedding and
// its tokens, and the block's LayerNorm, qkv, attention, MLP hidden and output maps. After the
// trunk: the four stage maps, the neck's laterals, level 2 and image_embed, feat_s0 / feat_s1,
// and the decoder's upscaled map and 3 mask logits.
int64_t viewFloatsAtLeast(const Sam2Config& c) {
  const int64_t S = c.imageSize, side = c.tokenSide(), t = side * side, c0 = c.embedDim, d = c.dModel;
  const int64_t firstBlock = 3 * S * S + 2 * t * c0 + t * c0 * (1 + 3 + 1 + 4 + 1);
  int64_t afterTrunk = 0;
  for (int64_t i = 0, tokens = t, width = c0; i < 4; ++i, tokens /= 4, width *= 2) afterTrunk += tokens * (width + d);
  afterTrunk += 2 * (t / 16) * d + t * (d / 8) + (t / 4) * (d / 4) + t * (d / 8) + 3 * t;
  return std::max(firstBlock, afterTrunk);
}

// The largest transients of one Hiera block (sam2_hiera_block.cpp), stages' maps before it
// included, over the trunk; the stage maps at its end.
struct TrunkFloats {
  int64_t largestBlock = 0, stages = 0;
};

TrunkFloats trunkFloats(const Sam2Config& c) {
  const std::vector<int64_t> ends = c.stageEnds();
  const std::vector<Sam2BlockSpec> blocks = c.blocks();
  TrunkFloats f;
  int64_t h = c.tokenSide(), w = c.tokenSide();
  for (size_t i = 0; i < blocks.size(); ++i) {
    const Sam2BlockSpec& b = blocks[i];
    const int64_t D = b.dim, Do = b.dimOut, T = h * w;
    const int64_t ho = b.qPool ? h / 2 : h, wo = b.qPool ? w / 2 : w, To = ho * wo;
    const int64_t win = b.window;
    const int64_t windowed = win > 0 ? ((h + win - 1) / win) * ((w + win - 1) / win) * win * win : T;
    const int64_t qTokens = b.qPool ? windowed / 4 : windowed;
    int64_t own = T * D;                                 // xn
    if (D != Do) own += T * Do + To * Do;                // projected, shortcut
    if (win > 0) own += windowed * D + To * Do;          // windows, merged
    own += 3 * windowed * Do;                            // qkv
    if (b.qPool) own += windowed * Do + qTokens * Do;    // q alone, pooled
    own += 2 * qTokens * Do + To * Do + 4 * To * Do + To * Do;  // attended, projected, yn, hidden, MLP out
    f.largestBlock = std::max(f.largestBlock, f.stages + T * D + To * Do + own);
    if (std::find(ends.begin(), ends.end(), int64_t(i)) != ends.end()) f.stages += To * Do;  // the stage maps stay
    h = ho;
    w = wo;
  }
  return f;
}

// What SAM2.1's refinement of one view holds at once at most (model/sam2_image_encoder.cpp,
// sam2_hiera_block.cpp, sam2_mask_decoder.cpp; views one after another). The trunk is submitted
// block by block: during block i, the 1024x1024 input, the patch embedding and its first tokens,
// the stage maps so far, the block's input and output and its own transients (sam2HieraBlock's
// tensors). Then the neck and the decoder in one submission: the stage maps, the input and the
// embedding, the laterals, level 2, image_embed, feat_s0 / feat_s1, and the decoder's maps (the
// prompt's downscaling, the dense embedding and keys, two two-way layers and the final
// attention at up to d wide, the upscaling, the mask logits).
int64_t viewFloats(const Sam2Config& c, int64_t hw) {
  const int64_t S = c.imageSize, side = c.tokenSide(), t = side * side, C0 = c.embedDim, d = c.dModel;
  const int64_t s2 = t / 16, base = 3 * S * S + 2 * t * C0;  // input, embedded, the first x
  const TrunkFloats trunk = trunkFloats(c);
  // the laterals of the four levels (t, t/4, t/16, t/64 tokens, d wide), level 2, image_embed,
  // feat_s0 / feat_s1
  const int64_t neck = (t + t / 4 + t / 16 + t / 64) * d + 2 * s2 * d + t * d / 8 + t * d / 16;
  const int64_t prompt = 2 * hw + 2 * t + 3 * 4 * (t / 4) + 2 * 16 * s2;  // binary, probs, prompt map, downscaling
  // the two-way layers and the final attention (queries, keys and values of the image tokens at
  // the cross-attention's width d / 2), the dense embedding and keys, the upscaling, the logits
  const int64_t decoder = s2 * (19 * d + 10 * (d / 2)) + 2 * t;
  return base + std::max(trunk.largestBlock, trunk.stages + neck + prompt + decoder);
}

Sam2Config sam2Config(const PackedModel& model) { return Sam2Config::fromJson(model.metadata().at("sam2_config")); }

class Sam2Refine : public PipelineStage {
 public:
  const char* name() const override { return "sam2_refine"; }
  std::vector<std::string> reads() const override { return {"images", "cv_drp_input.prob", "cv_drp_target.prob"}; }
  std::vector<std::string> writes() const override { return {"refined_input"}; }
  std::vector<std::string> weightModules(const StageSizing&) const override { return {"sam2"}; }
  bool ownsSubmissions() const override { return true; }

  StageMemory memory(const StageSizing& s) const override {
    const RequestShape& q = s.shape;
    const Sam2Config c = sam2Config(s.model);
    const int64_t hw = q.height * q.width, views = motionViews(q), t2 = c.tokenSide() * c.tokenSide();
    StageMemory m;
    m.kept = views * hw + viewFloatsAtLeast(c);  // the refined masks, and one view's maps at least
    m.atEncodeEnd = 2 * views * hw;              // refined masks of the views
    m.own = t2 * c.embedDim + (t2 / 16) * c.dModel + 6 * c.dModel;  // position table, dense PE, tokens
    return m;
  }
  // During the refinement (after CV-DRP): the views' images, prompts, binary and refined maps,
  // and one view's refinement.
  int64_t moment(const StageSizing& s, const MemoryMoments& around) const override {
    const int64_t hw = s.shape.height * s.shape.width, views = motionViews(s.shape);
    return around.encode + 3 * views * hw + 4 * views * hw + viewFloats(sam2Config(s.model), hw);
  }

  void record(StageRun& r) override {
    const Request& q = r.request;
    const int64_t v = q.plan.views, h = q.height, w = q.width;
    Sam2Refiner& sam2 = r.models.sam2();
    const auto t0 = std::chrono::steady_clock::now();
    // each submission's GPU time is the stage's; its wall time is the whole refinement's (below)
    const auto onSubmission = [&r](const Recorder& rec) { r.submitted(rec, 0.0); };
    const Tensor given = q.refinePrompts.empty() ? Tensor() : r.engine.fromFloats({v, h, w}, q.refinePrompts);
    const auto refineViews = [&](const std::vector<int64_t>& positions, const Tensor& cvDrp, std::vector<float>& masks) {
      const int64_t count = int64_t(positions.size());
      Recorder rec(r.engine);
      const Tensor viewImages = selectViews(rec, r.at("images"), positions, 3 * h * w, {3, h, w});
      const Tensor prompts = given.defined() ? selectViews(rec, given, positions, h * w, {h, w}) : cvDrp.reshape({count, h, w});
      rec.run();
      Sam2Refined out = sam2.refine(viewImages, prompts, r.profile ? onSubmission : std::function<void(const Recorder&)>());
      masks = std::move(out.masks);
      for (size_t j = 0; j < positions.size(); ++j) {
        const Sam2ViewRefinement& s = out.views[j];
        r.encoded.refineViews.push_back({positions[j], s.skipped, s.dynamicPixels, s.iou, s.chosen, s.logits});
      }
    };
    refineViews(q.plan.inputs, r.optional("cv_drp_input.prob"), r.encoded.refinedInput);
    if (q.targetMotion && !q.plan.targets.empty())
      refineViews(q.plan.targets, r.optional("cv_drp_target.prob"), r.encoded.refinedTarget);
    r.recordTime(name(), 0.0, std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count(), 0.0,
                 {});
    const Tensor refined = r.engine.fromFloats({int64_t(q.plan.inputs.size()), 1, h, w}, r.encoded.refinedInput);
    r.tensors["refined_input"] = refined;
    r.keep("refined_input", refined);
  }

 private:
  static int64_t motionViews(const RequestShape& q) { return q.inputs + (q.targetMotion ? q.targets : 0); }
};

}  // namespace

std::unique_ptr<PipelineStage> sam2Refine() { return std::make_unique<Sam2Refine>(); }

}  // namespace spar::stages
