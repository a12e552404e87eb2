// The semantic stages of models with the semantic branch (model/stages/stages.h): LSeg's
// features of the input views (model/lseg.h; SPAR feeds it the [0, 1] images as they are), left
// out when the request brings its own; then the semantic tokens: the features with their rays,
// pooled per 16x16 pixels, projected (model/semantic_tokens.h), gated like the image tokens.
#include "model/nonfinite_watch.h"
#include "model/stage_models.h"
#include "model/stages/select_views.h"
#include "model/stages/stages.h"

namespace spar::stages {
namespace {

class LSeg : public PipelineStage {
 public:
  const char* name() const override { return "lseg"; }
  std::vector<std::string> reads() const override { return {"images"}; }
  std::vector<std::string> writes() const override { return {"lseg_features"}; }
  std::vector<std::string> weightModules(const StageSizing&) const override { return {"lseg"}; }
  StageMemory memory(const StageSizing& s) const override {
    const SparConfig& c = s.config;
    const RequestShape& q = s.shape;
    const int64_t k = q.inputs, hw = q.height * q.width;
    const LSegConfig lc = LSegConfig::fromJson(c.raw, "memory estimate");
    StageMemory m;
    m.kept = m.atEncodeEnd = k * c.semanticDim * (hw / 4) + 3 * k * hw;  // the features, the inputs' images
    m.own = LSegEncoder::ownFloats(lc, k, q.height, q.width);            // lseg.cpp: its buffers and tables
    m.workspace.push_back({k * (1 + (q.height / lc.patchSize) * (q.width / lc.patchSize)), lc.width, lc.mlpHidden()});
    return m;
  }
  void record(StageRun& r) override {
    const Request& q = r.request;
    const int64_t k = int64_t(q.plan.inputs.size()), h = q.height, w = q.width;
    LSegEncoder& lseg = r.models.lseg();
    const Tensor features = r.engine.tensor({k, r.config.semanticDim, h / 2, w / 2});
    const Tensor inputImages = selectViews(r.rec(), r.at("images"), q.plan.inputs, 3 * h * w, {3, h, w});
    lseg.forward(r.rec(), inputImages, features, r.ws);
    r.watch.watch(r.rec(), name(), features);
    r.tensors["lseg_features"] = features;
    r.keep("lseg_features", features);
  }
};

class SemanticTokensStage : public PipelineStage {
 public:
  const char* name() const override { return "semantic_tokens"; }
  std::vector<std::string> reads() const override {
    return {"lseg_features", "plucker", "cv_drp_input.prob", "refined_input"};
  }
  std::vector<std::string> writes() const override { return {"gated_semantic_tokens"}; }
  std::vector<std::string> weightModules(const StageSizing&) const override {
    return {"semantic_proj", "view_type_embedding"};
  }
  StageMemory memory(const StageSizing& s) const override {
    const SparConfig& c = s.config;
    const RequestShape& q = s.shape;
    const int64_t k = q.inputs, ns = (q.height / 16) * (q.width / 16), half = q.height * q.width / 4;
    StageMemory m;
    m.kept = m.atEncodeEnd = 2 * k * ns * c.d;  // the semantic tokens, gated
    if (q.lsegGiven) m.kept = m.atEncodeEnd += k * c.semanticDim * half;  // the request's features, uploaded
    m.transient = k * ns + k * (c.semanticDim + 6) * (half + 2 * ns);  // their concat, pooling, rows
    return m;
  }
  void record(StageRun& r) override {
    const Request& q = r.request;
    const int64_t k = int64_t(q.plan.inputs.size()), h = q.height, w = q.width, d = r.config.d;
    Tensor features = r.optional("lseg_features");
    if (!q.lsegFeatures.empty()) {
      features = r.engine.fromFloats({k, r.config.semanticDim, h / 2, w / 2}, q.lsegFeatures);
      r.keep("lseg_features", features);
    }
    SemanticTokens& semantic = r.models.semantic();
    const int64_t hs = h / 16, ws = w / 16;
    const Tensor semTokens = r.engine.tensor({k * hs * ws, d});
    const Tensor pooled = r.keepIntermediates ? r.engine.tensor({k, r.config.semanticDim + 6, hs, ws}) : Tensor();
    Tensor gatedSem = semTokens;
    semantic.forward(r.rec(), features, r.at("plucker"), q.plan.inputs, semTokens, pooled);
    if (const Tensor mask = gateMask(r); mask.defined()) {
      gatedSem = r.engine.tensor({k * hs * ws, d});
      const Tensor dynSem = r.engine.tensor({k, 1, hs, ws});
      r.models.gating().gate(r.rec(), semTokens, mask, dynSem, gatedSem);
      r.keep("dynamic_patch_sem", dynSem);
    }
    r.watch.watch(r.rec(), name(), gatedSem);
    r.tensors["gated_semantic_tokens"] = gatedSem;
    r.keep("semantic_in", pooled);
    r.keep("semantic_tokens", semTokens);
    r.keep("gated_semantic_tokens", gatedSem);
  }
};

}  // namespace

std::unique_ptr<PipelineStage> lseg() { return std::make_unique<LSeg>(); }
std::unique_ptr<PipelineStage> semanticTokens() { return std::make_unique<SemanticTokensStage>(); }

}  // namespace spar::stages
