// A render call (model/stages/stages.h, phase Render): the rays of the cameras to render (their
// dispatches under the stage name "render_rays"), then the decoder over ray queries and the
// scene tokens, the RGB head and, with semanticFeatures, the semantic head (model/renderer.h),
// in the render call's one submission. Reads "render_c2w" [R, 4, 4] and "render_fxfycxcy"
// [R, 4]; writes "rgb" and "semantic_features".
#include <algorithm>

#include "model/nonfinite_watch.h"
#include "model/plucker_rays.h"
#include "model/stage_models.h"
#include "model/stages/stages.h"

namespace spar::stages {
namespace {

class RendererStage : public PipelineStage {
 public:
  const char* name() const override { return "renderer"; }
  StagePhase phase() const override { return StagePhase::Render; }
  std::vector<std::string> reads() const override { return {"render_c2w", "render_fxfycxcy", "scene_encoder_out"}; }
  std::vector<std::string> writes() const override { return {"rgb", "semantic_features"}; }
  std::vector<std::string> weightModules(const StageSizing& s) const override {
    std::vector<std::string> modules = {"transformer_decoder", "decoder_ln", "image_token_decoder",
                                        "target_pose_tokenizer2", "view_type_embedding"};
    if (s.config.semanticDecoding()) modules.push_back("target_pose_tokenizer_semantic");  // the semantic queries
    if (s.shape.semantic) modules.insert(modules.end(), {"semantic_token_decoder", "semantic_feature_expansion"});
    return modules;
  }
  StageMemory memory(const StageSizing& s) const override {
    const SparConfig& c = s.config;
    const RequestShape& q = s.shape;
    const int64_t r = q.renderChunk, hw = q.height * q.width, d = c.d, p = c.patchSize, sc = c.sceneTokens;
    const int64_t n = (q.height / p) * (q.width / p), queries = c.semanticDecoding() ? 2 * n : n;
    StageMemory m;
    if (r > 0) {
      // queries (RGB, semantic), decoder sequence, decoded tokens, RGB patches and image, rays
      m.kept = r * (queries * d + (queries + sc) * d + n * d + n * p * p * 3 + 3 * hw + 6 * hw);
      if (q.semantic) m.kept += r * c.semanticDim * (hw / 4);
    }
    const int64_t views = mostViews(q);
    m.renderOutput = q.semantic ? views * c.semanticDim * (hw / 4) : 0;
    m.workspace.push_back({std::min<int64_t>(views, Renderer::kViewsPerBatch) * (queries + sc), d, 4 * d});
    return m;
  }
  // Its cameras, rays and images, and every view's queries, ray patches, decoder sequence, tokens
  // and RGB patches (and the semantic head's maps) at once (its batches share one submission);
  // the previous call's features until the new ones replace them.
  int64_t moment(const StageSizing& s, const MemoryMoments& around) const override {
    const SparConfig& c = s.config;
    const RequestShape& q = s.shape;
    const int64_t hw = q.height * q.width, d = c.d, n = (q.height / c.patchSize) * (q.width / c.patchSize);
    const int64_t queries = c.semanticDecoding() ? 2 * n : n, views = mostViews(q);
    int64_t perView = 3 * n * d + (queries + c.sceneTokens) * d + 6 * hw + 3 * hw;
    if (c.semanticDecoding()) perView += n * d + 6 * hw;
    if (q.semantic) perView += 7 * n * d + 2 * c.semanticHidden * hw + c.semanticHidden * (hw / 4);
    return around.between + 20 * views + 9 * views * hw + 2 * around.renderOutput + views * perView;
  }
  void record(StageRun& r) override {
    const Request& q = r.request;
    const int64_t h = q.height, w = q.width;
    const Tensor& c2w = r.at("render_c2w");
    const int64_t count = c2w.shape()[0];
    Renderer& renderer = r.models.renderer();
    Recorder& rec = r.rec();
    const Tensor rays = r.engine.tensor({count, 6, h, w}), rgb = r.engine.tensor({count, 3, h, w});
    rec.setStage("render_rays");
    pluckerRays(rec, c2w, r.at("render_fxfycxcy"), rays);
    r.watch.watch(rec, "render_rays", rays);
    rec.setStage(name());
    RenderTrace trace;
    const Tensor features = q.semanticFeatures ? r.engine.tensor({count, r.config.semanticDim, h / 2, w / 2}) : Tensor();
    renderer.forward(rec, rays, r.at("scene_encoder_out").view(0, {r.config.sceneTokens, r.config.d}), rgb, r.ws,
                     features, r.keepIntermediates ? &trace : nullptr);
    r.watch.watch(rec, name(), rgb);
    r.watch.watch(rec, name(), features);
    r.tensors["rgb"] = rgb;
    r.tensors["semantic_features"] = features;
    r.keep("render_plucker", rays);
    r.keep("rgb_queries", trace.rgbQueries);
    r.keep("decoder_in", trace.decoderIn);
    r.keep("decoder_out", trace.decoderOut);
    r.keep("rgb_tokens", trace.rgbTokens);
    r.keep("semantic_queries", trace.semanticQueries);
    r.keep("semantic_out_tokens", trace.semanticOutTokens);
    r.keep("semantic_hidden", trace.semanticHidden);
    r.keep("semantic_features", features);
    r.keep("rgb", rgb);
  }

 private:
  // The most views one render call holds: a render chunk, the targets, at least one.
  static int64_t mostViews(const RequestShape& q) { return std::max<int64_t>({q.renderChunk, q.targets, 1}); }
};

}  // namespace

std::unique_ptr<PipelineStage> renderer() { return std::make_unique<RendererStage>(); }

}  // namespace spar::stages
