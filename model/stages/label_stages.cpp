// The label phases (model/stages/stages.h): CLIP's text encoder over the prompts' token ids, once
// for a set of prompts (model/clip_text.h, phase Prompts), and the label maps of a render call's
// semantic features (model/label_maps.h, phase Labels). Each submits its own work.
#include <algorithm>
#include <chrono>

#include "model/clip_text.h"
#include "model/prompt_label_maps.h"
#include "model/stage_models.h"
#include "model/stages/stages.h"

namespace spar::stages {
namespace {

int64_t mostViews(const RequestShape& q) { return std::max<int64_t>({q.renderChunk, q.targets, 1}); }

class TextEncoder : public PipelineStage {
 public:
  const char* name() const override { return "text_encoder"; }
  StagePhase phase() const override { return StagePhase::Prompts; }
  bool ownsSubmissions() const override { return true; }
  std::vector<std::string> reads() const override { return {}; }
  std::vector<std::string> writes() const override { return {}; }  // PromptWork::text
  std::vector<std::string> weightModules(const StageSizing&) const override { return {"clip"}; }
  StageMemory memory(const StageSizing&) const override { return {}; }
  // prompt_label_maps.cpp / clip_text.cpp: the projection's copy, the embeddings, the token rows
  // of every prompt at the context length, and CLIP's own workspace
  int64_t moment(const StageSizing& s, const MemoryMoments& around) const override {
    if (!s.config.raw.contains("clip")) return 0;
    const ClipTextConfig cc = ClipTextConfig::fromJson(s.config.raw.at("clip"), "memory estimate");
    const int64_t prompts = s.shape.prompts, rows = std::max<int64_t>(prompts, 1) * cc.contextLength, wc = cc.width;
    return around.between + cc.embedDim * wc + 2 * prompts * cc.embedDim + 2 * rows + rows * wc +
           2 * std::max<int64_t>(prompts, 1) * wc + 2 * rows * wc + rows * 4 * wc;
  }
  void record(StageRun& r) override {
    PromptWork& p = *r.prompts;
    *p.text = encodePrompts(r.engine, r.models.model, r.config, r.models.weights.matrixType(), *p.ids, p.count);
    r.recordTime(name(), p.text->gpuMs, p.text->wallMs, p.text->buildMs, p.text->counts);
  }
};

class LabelMaps : public PipelineStage {
 public:
  const char* name() const override { return "labels"; }
  StagePhase phase() const override { return StagePhase::Labels; }
  bool ownsSubmissions() const override { return true; }
  std::vector<std::string> reads() const override { return {"semantic_features"}; }
  std::vector<std::string> writes() const override { return {}; }  // PromptWork::maps
  std::vector<std::string> weightModules(const StageSizing&) const override { return {}; }
  StageMemory memory(const StageSizing&) const override { return {}; }
  // label_maps.cpp: the maps, the scores, the normalized features and prompts
  int64_t moment(const StageSizing& s, const MemoryMoments& around) const override {
    const RequestShape& q = s.shape;
    const int64_t hw = q.height * q.width, views = mostViews(q);
    return around.between + around.renderOutput + views * hw + 2 * views * q.prompts * (hw / 4) + around.renderOutput +
           q.prompts * s.config.semanticDim;
  }
  void record(StageRun& r) override {
    PromptWork& p = *r.prompts;
    const auto t0 = std::chrono::steady_clock::now();
    *p.maps = computeLabelMaps(r.engine, r.at("semantic_features"), *p.text, p.scores);
    const double wall = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    r.recordTime(name(), p.maps->gpuMs, wall, p.maps->buildMs, p.maps->counts);
  }
};

}  // namespace

std::unique_ptr<PipelineStage> textEncoder() { return std::make_unique<TextEncoder>(); }
std::unique_ptr<PipelineStage> labels() { return std::make_unique<LabelMaps>(); }

}  // namespace spar::stages
