// The scene encoder (model/stages/stages.h, model/scene_encoder.h): the scene code, the gated
// input tokens and the gated semantic tokens through the encoder; its first S rows are the scene
// tokens every render call decodes from.
#include "model/nonfinite_watch.h"
#include "model/stage_models.h"
#include "model/stages/stages.h"

namespace spar::stages {
namespace {

class SceneEncoderStage : public PipelineStage {
 public:
  const char* name() const override { return "scene_encoder"; }
  std::vector<std::string> reads() const override { return {"gated_tokens", "gated_semantic_tokens"}; }
  std::vector<std::string> writes() const override { return {"scene_encoder_out"}; }
  std::vector<std::string> weightModules(const StageSizing&) const override {
    return {"scene_code", "transformer_encoder_geom"};
  }
  StageMemory memory(const StageSizing& s) const override {
    const SparConfig& c = s.config;
    const RequestShape& q = s.shape;
    const int64_t n = (q.height / c.patchSize) * (q.width / c.patchSize);
    const int64_t ns = c.useLseg ? (q.height / 16) * (q.width / 16) : 0;
    const int64_t rows = c.sceneTokens + q.inputs * n + q.inputs * ns;
    StageMemory m;
    m.kept = rows * c.d;             // the sequence, kept for the render calls
    m.atEncodeEnd = 2 * rows * c.d;  // the sequence and its input
    m.forRenders = rows * c.d;
    m.workspace.push_back({rows, c.d, 4 * c.d});  // scene_encoder.cpp
    return m;
  }
  void record(StageRun& r) override {
    const int64_t d = r.config.d;
    const Tensor& gated = r.at("gated_tokens");
    const Tensor gatedSem = r.optional("gated_semantic_tokens");
    SceneEncoder& scene = r.models.scene();
    const int64_t rows = r.config.sceneTokens + gated.numel() / d + (gatedSem.defined() ? gatedSem.numel() / d : 0);
    const Tensor seq = r.engine.tensor({rows, d});
    const Tensor sceneIn = r.keepIntermediates ? r.engine.tensor({rows, d}) : Tensor();
    std::vector<Tensor> parts{gated};
    if (gatedSem.defined()) parts.push_back(gatedSem);
    scene.forward(r.rec(), parts, seq, r.ws, sceneIn);
    r.watch.watch(r.rec(), name(), seq);
    r.tensors["scene_encoder_out"] = seq;
    r.keep("scene_encoder_in", sceneIn);
    r.keep("scene_encoder_out", seq);
    r.keep("scene_tokens", seq.view(0, {r.config.sceneTokens, d}));
  }
};

}  // namespace

std::unique_ptr<PipelineStage> sceneEncoder() { return std::make_unique<SceneEncoderStage>(); }

}  // namespace spar::stages
