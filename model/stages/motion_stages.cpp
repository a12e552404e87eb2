// The motion stages (model/stages/stages.h), left out for a scene declared static: DINOv3's
// patch tokens of every view (model/dino_v3.h), then CV-DRP's P(dynamic) of the input views, and
// of the targets with targetMotion (model/cv_drp.h), in one submission.
#include "model/nonfinite_watch.h"
#include "model/stage_models.h"
#include "model/stages/stages.h"
#include "model/transformer_block.h"

namespace spar::stages {
namespace {

int64_t patches(const SparConfig& c, const RequestShape& q) {
  return (q.height / c.patchSize) * (q.width / c.patchSize);
}

class DinoV3Stage : public PipelineStage {
 public:
  const char* name() const override { return "dino_v3"; }
  std::vector<std::string> reads() const override { return {"images"}; }
  std::vector<std::string> writes() const override { return {"dino"}; }
  std::vector<std::string> weightModules(const StageSizing&) const override { return {"dino"}; }
  StageMemory memory(const StageSizing& s) const override {
    const SparConfig& c = s.config;
    const RequestShape& q = s.shape;
    const DinoConfig& dc = c.dino;
    StageMemory m;
    m.kept = m.atEncodeEnd = q.views * patches(c, q) * c.d;  // the patch tokens
    // dino_v3.cpp: its buffers, RoPE tables and derived weights, and the masked qkv biases
    m.own = DinoV3::ownFloats(dc, q.views, q.height, q.width) + dc.depth * 3 * dc.embedDim;
    const int64_t nd = (q.height / dc.patchSize) * (q.width / dc.patchSize);
    m.workspace.push_back({q.views * (1 + dc.storageTokens + nd), dc.embedDim, dc.ffnHidden()});
    return m;
  }
  void record(StageRun& r) override {
    const Request& q = r.request;
    DinoV3& dino = r.models.dino();
    const Tensor tokens = r.engine.tensor({q.plan.views, (q.height / r.config.patchSize) * (q.width / r.config.patchSize),
                                           r.config.d});
    dino.forward(r.rec(), r.at("images"), tokens, r.ws);
    r.watch.watch(r.rec(), name(), tokens);
    r.tensors["dino"] = tokens;
    r.keep("dino", tokens);
  }
};

class CvDrpStage : public PipelineStage {
 public:
  const char* name() const override { return "cv_drp"; }
  std::vector<std::string> reads() const override { return {"dino", "img_tokens", "ray_tokens"}; }
  std::vector<std::string> writes() const override { return {"cv_drp_input.prob", "cv_drp_target.prob"}; }
  std::vector<std::string> weightModules(const StageSizing&) const override { return {"cv_drp"}; }
  StageMemory memory(const StageSizing& s) const override {
    const SparConfig& c = s.config;
    const RequestShape& q = s.shape;
    const int64_t k = q.inputs, t = q.targets, hw = q.height * q.width, n = patches(c, q), d = c.d;
    const bool targets = q.targetMotion && t > 0;
    StageMemory m;
    m.kept = 2 * k * hw;  // the inputs' logits and P(dynamic)
    m.atEncodeEnd = 2 * k * hw + (targets ? 2 * t * hw : 0);
    // cv_drp.cpp: the inputs' call, then the targets' in the same submission (a larger scratch
    // or workspace for the targets leaves the inputs' pending beside it: both counted)
    const int64_t pairsIn = CvDrp::pairCount(k, CvDrpMode::Input);
    m.own = CvDrp::scratchFloats(d, k, pairsIn, n);
    m.workspace.push_back({2 * pairsIn * n, d, 4 * d});
    if (targets) {
      const int64_t pairsT = CvDrp::pairCount(t, CvDrpMode::Target);
      const int64_t inRows = std::max<int64_t>(2 * pairsIn * n, 1);
      m.own += CvDrp::scratchFloats(d, t, pairsT, n) + 2 * inRows * d + inRows * std::max(3 * d, 4 * d);
      m.workspace.push_back({2 * pairsT * n, d, 4 * d});
    }
    return m;
  }
  void record(StageRun& r) override {
    const Request& q = r.request;
    const int64_t k = int64_t(q.plan.inputs.size()), h = q.height, w = q.width;
    const int64_t gh = h / r.config.patchSize, gw = w / r.config.patchSize;
    CvDrp& cvDrp = r.models.cvDrp();
    const Tensor& dino = r.at("dino");
    const Tensor& img = r.at("img_tokens");
    const Tensor& ray = r.at("ray_tokens");
    const Tensor logitsInput = r.engine.tensor({k, 1, h, w}), probInput = r.engine.tensor({k, 1, h, w});
    cvDrp.forward(r.rec(), dino, img, ray, q.plan.inputs, CvDrpMode::Input, gh, gw, logitsInput, probInput, r.ws);
    r.keep("cv_drp_input.logits", logitsInput);
    r.keep("cv_drp_input.prob", probInput);
    Tensor probTarget;
    const int64_t t = int64_t(q.plan.targets.size());
    if (q.targetMotion && t > 0) {
      const Tensor logitsTarget = r.engine.tensor({t, 1, h, w});
      probTarget = r.engine.tensor({t, 1, h, w});
      cvDrp.forward(r.rec(), dino, img, ray, q.plan.targets, CvDrpMode::Target, gh, gw, logitsTarget, probTarget, r.ws);
      r.keep("cv_drp_target.logits", logitsTarget);
      r.keep("cv_drp_target.prob", probTarget);
      r.tensors["cv_drp_target.prob"] = probTarget;
    }
    r.watch.watch(r.rec(), name(), probInput);
    r.watch.watch(r.rec(), name(), probTarget);
    r.tensors["cv_drp_input.prob"] = probInput;
  }
};

}  // namespace

std::unique_ptr<PipelineStage> dinoV3() { return std::make_unique<DinoV3Stage>(); }
std::unique_ptr<PipelineStage> cvDrp() { return std::make_unique<CvDrpStage>(); }

}  // namespace spar::stages
