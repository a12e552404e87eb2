// mlp_fuse and the gating of the input tokens (model/stages/stages.h, model/gating.h): the
// inputs' image and ray tokens fused, then gated by their motion masks: CV-DRP's, or the refined
// ones with MaskSource::Refined. Without masks (assumeStatic) or without gating the fused tokens
// go on as they are.
#include "model/nonfinite_watch.h"
#include "model/stage_models.h"
#include "model/stages/stages.h"

namespace spar::stages {

// What gates a request's input tokens (and its semantic tokens): the refined masks with
// MaskSource::Refined, else CV-DRP's; undefined without masks or without gating.
Tensor gateMask(const StageRun& r) {
  if (!r.request.gating) return Tensor();
  return r.request.maskSource == MaskSource::Refined ? r.optional("refined_input") : r.optional("cv_drp_input.prob");
}

namespace {

class Gating : public PipelineStage {
 public:
  const char* name() const override { return "gating"; }
  std::vector<std::string> reads() const override {
    return {"img_tokens", "ray_tokens", "cv_drp_input.prob", "refined_input"};
  }
  std::vector<std::string> writes() const override { return {"gated_tokens"}; }
  std::vector<std::string> weightModules(const StageSizing&) const override {
    return {"mlp_fuse", "mask_token", "view_type_embedding"};
  }
  StageMemory memory(const StageSizing& s) const override {
    const SparConfig& c = s.config;
    const RequestShape& q = s.shape;
    const int64_t k = q.inputs, n = (q.height / c.patchSize) * (q.width / c.patchSize), d = c.d;
    const int64_t ns = c.useLseg ? (q.height / 16) * (q.width / 16) : 0;
    StageMemory m;
    m.kept = m.atEncodeEnd = 2 * k * n * d;  // fused and gated input tokens
    m.transient = k * n;                     // the dynamic share of each patch
    // gating.cpp: its concat and hidden buffers, and code tables (the image grid, LSeg's when it differs)
    m.own = 3 * k * n * d + (n + 1) * d + (ns + 1) * d;
    return m;
  }
  void record(StageRun& r) override {
    const Request& q = r.request;
    const int64_t k = int64_t(q.plan.inputs.size()), d = r.config.d;
    const int64_t gh = q.height / r.config.patchSize, gw = q.width / r.config.patchSize;
    TokenGating& gating = r.models.gating();
    const Tensor fused = r.engine.tensor({k * gh * gw, d});
    Tensor gated = fused;
    gating.fuse(r.rec(), r.at("img_tokens"), r.at("ray_tokens"), q.plan.inputs, fused);
    if (const Tensor mask = gateMask(r); mask.defined()) {
      gated = r.engine.tensor({k * gh * gw, d});
      const Tensor dynPatch = r.engine.tensor({k, 1, gh, gw});
      gating.gate(r.rec(), fused, mask, dynPatch, gated);
      r.keep("dynamic_patch", dynPatch);
    }
    r.watch.watch(r.rec(), name(), gated);
    r.tensors["gated_tokens"] = gated;
    r.keep("fused_tokens", fused);
    r.keep("gated_tokens", gated);
  }
};

}  // namespace

std::unique_ptr<PipelineStage> gating() { return std::make_unique<Gating>(); }

}  // namespace spar::stages
