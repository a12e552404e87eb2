// The stages from the views to the cameras (model/stages/stages.h): image tokens of every view
// with its spatial-temporal code, and camera tokens (model/view_tokens.h); the pose encoder and
// heads (model/pose_estimator.h); Plücker rays of the estimated cameras and their ray tokens
// (model/plucker_rays.h). Sizes: V views of H x W, n = (H / p)(W / p) patches, D wide.
#include "model/nonfinite_watch.h"
#include "model/plucker_rays.h"
#include "model/stage_models.h"
#include "model/stages/stages.h"
#include "model/transformer_block.h"

namespace spar::stages {
namespace {

struct Sizes {
  int64_t v, hw, n, d;
};

Sizes sizesOf(const SparConfig& c, const RequestShape& q) {
  return {q.views, q.height * q.width, (q.height / c.patchSize) * (q.width / c.patchSize), c.d};
}

class ImageTokens : public PipelineStage {
 public:
  const char* name() const override { return "image_tokens"; }
  std::vector<std::string> reads() const override { return {"images"}; }
  std::vector<std::string> writes() const override { return {"images", "img_tokens", "cam_tokens_in"}; }
  std::vector<std::string> weightModules(const StageSizing&) const override {
    return {"image_tokenizer", "pe_embedder", "temporal_pe_embedder", "cam_code"};
  }
  StageMemory memory(const StageSizing& s) const override {
    const SparConfig& c = s.config;
    const RequestShape& q = s.shape;
    const auto [v, hw, n, d] = sizesOf(c, q);
    StageMemory m;
    m.kept = m.atEncodeEnd = 3 * v * hw + 2 * v * n * d + v * d;  // images, raw and coded tokens, camera tokens
    m.transient = 3 * v * hw + 3 * v * hw + v * n * d + v * d;    // scaled images, patches, hidden rows
    m.own = v * n * d + v * d;  // view_tokens.cpp: the image and camera codes (per view count)
    return m;
  }
  void record(StageRun& r) override {
    const Request& q = r.request;
    const int64_t v = q.plan.views, h = q.height, w = q.width, d = r.config.d;
    const int64_t n = (h / r.config.patchSize) * (w / r.config.patchSize);
    const Tensor images = r.engine.fromFloats({v, 3, h, w}, q.images);
    const Tensor raw = r.engine.tensor({v, n, d}), imgTokens = r.engine.tensor({v, n, d});
    const Tensor code = r.keepIntermediates ? r.engine.tensor({v, n, d}) : Tensor();
    const Tensor cam = r.engine.tensor({v, d});
    r.models.tokenizer().imageTokens(r.rec(), images, raw, imgTokens, code);
    r.models.tokenizer().cameraTokens(r.rec(), v, cam);
    r.watch.reset();  // the first stage: a new request's values
    r.watch.watch(r.rec(), name(), imgTokens);
    r.tensors["images"] = images;
    r.tensors["img_tokens"] = imgTokens;
    r.tensors["cam_tokens_in"] = cam;
    r.keep("images", images);
    r.keep("img_tokens_raw", raw);
    r.keep("pe_code", code);
    r.keep("img_tokens", imgTokens);
    r.keep("cam_tokens_in", cam);
  }
};

class PoseEstimatorStage : public PipelineStage {
 public:
  const char* name() const override { return "pose_estimator"; }
  std::vector<std::string> reads() const override { return {"cam_tokens_in", "img_tokens"}; }
  std::vector<std::string> writes() const override { return {"c2w", "fxfycxcy"}; }
  std::vector<std::string> weightModules(const StageSizing&) const override {
    return {"transformer_encoder", "pose_predictor"};
  }
  StageMemory memory(const StageSizing& s) const override {
    const SparConfig& c = s.config;
    const RequestShape& q = s.shape;
    const auto [v, hw, n, d] = sizesOf(c, q);
    StageMemory m;
    m.kept = m.atEncodeEnd = (v + v * n) * d;  // the pose encoder's output
    m.transient = d + 1 + (v - 1) * (3 * d + 9);  // pose_head.cpp: the canonical and relative heads
    m.own = 2 * 20 * v;     // the cameras, c2w and fxfycxcy: old and new at a second encode
    m.forRenders = 20 * v;  // the cameras stay for the render calls
    m.workspace.push_back({v + v * n, d, 4 * d});  // pose_estimator.cpp
    return m;
  }
  void record(StageRun& r) override {
    const int64_t v = r.request.plan.views, d = r.config.d;
    const Tensor& img = r.at("img_tokens");
    PoseEstimator& pose = r.models.pose();
    const Tensor enc = r.engine.tensor({v + img.shape()[0] * img.shape()[1], d});
    const Tensor c2w = r.engine.tensor({v, 4, 4}), fxfycxcy = r.engine.tensor({v, 4});
    pose.forward(r.rec(), r.at("cam_tokens_in"), img, enc, c2w, fxfycxcy, r.ws);
    r.watch.watch(r.rec(), name(), c2w);
    r.watch.watch(r.rec(), name(), fxfycxcy);
    r.tensors["c2w"] = c2w;
    r.tensors["fxfycxcy"] = fxfycxcy;
    r.keep("pose_encoder_out", enc);
    r.keep("cam_tokens", enc.view(0, {v, d}));
    r.keep("c2w", c2w);
    r.keep("fxfycxcy", fxfycxcy);
  }
};

// Every view's rays (CV-DRP sees the targets' too) and their tokens.
class Rays : public PipelineStage {
 public:
  const char* name() const override { return "rays"; }
  std::vector<std::string> reads() const override { return {"c2w", "fxfycxcy"}; }
  std::vector<std::string> writes() const override { return {"plucker", "ray_tokens"}; }
  std::vector<std::string> weightModules(const StageSizing&) const override {
    return {"target_pose_tokenizer"};
  }
  StageMemory memory(const StageSizing& s) const override {
    const SparConfig& c = s.config;
    const RequestShape& q = s.shape;
    const auto [v, hw, n, d] = sizesOf(c, q);
    StageMemory m;
    m.kept = m.atEncodeEnd = 6 * v * hw + v * n * d;  // rays, ray tokens
    m.transient = 6 * v * hw;                         // their patches
    return m;
  }
  void record(StageRun& r) override {
    const Request& q = r.request;
    const int64_t v = q.plan.views, h = q.height, w = q.width, d = r.config.d;
    const int64_t n = (h / r.config.patchSize) * (w / r.config.patchSize);
    const Tensor rays = r.engine.tensor({v, 6, h, w}), rayTokens = r.engine.tensor({v, n, d});
    pluckerRays(r.rec(), r.at("c2w"), r.at("fxfycxcy"), rays);
    r.models.tokenizer().rayTokens(r.rec(), "target_pose_tokenizer", rays, rayTokens);
    r.watch.watch(r.rec(), name(), rayTokens);
    r.tensors["plucker"] = rays;
    r.tensors["ray_tokens"] = rayTokens;
    r.keep("plucker", rays);
    r.keep("ray_tokens", rayTokens);
  }
};

}  // namespace

std::unique_ptr<PipelineStage> imageTokens() { return std::make_unique<ImageTokens>(); }
std::unique_ptr<PipelineStage> poseEstimator() { return std::make_unique<PoseEstimatorStage>(); }
std::unique_ptr<PipelineStage> rays() { return std::make_unique<Rays>(); }

}  // namespace spar::stages
