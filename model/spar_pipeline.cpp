// SPAR's photometric pipeline (model/spar_pipeline.h): the stages in order, each recorded and
// run as one submission so that its GPU time (timestamps) and wall time are known.
#include "model/spar_pipeline.h"
#include "model/camera_checks.h"
#include "model/nonfinite_watch.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <set>

#include "engine/error.h"
#include "engine/ops/copy2d.h"
#include "engine/recorder.h"
#include "model/cv_drp.h"
#include "model/dino_v3.h"
#include "model/gating.h"
#include "model/lseg.h"
#include "model/plucker_rays.h"
#include "model/pose_estimator.h"
#include "model/renderer.h"
#include "model/sam2_config.h"
#include "model/sam2_refinement.h"
#include "model/scene_encoder.h"
#include "model/semantic_tokens.h"
#include "model/stack.h"
#include "model/view_tokens.h"

namespace spar {

void ViewPlan::validate() const {
  if (views < 1) throw Error("no views given");
  if (inputs.empty()) throw Error("at least one input view is needed");
  std::set<int64_t> seen;
  for (const auto* list : {&inputs, &targets})
    for (size_t i = 0; i < list->size(); ++i) {
      const int64_t v = (*list)[i];
      if (v < 0 || v >= views)
        throw Error("view position " + std::to_string(v) + " is outside the sequence of " + std::to_string(views) +
                    " frames");
      if (i > 0 && v <= (*list)[i - 1]) throw Error("view positions must be increasing");
      if (!seen.insert(v).second) throw Error("view " + std::to_string(v) + " is both an input and a target");
    }
}

// Everything built from the weights, constructed on first use so that a request that skips a
// stage never uploads its weights.
struct SparPipeline::Stages {
  std::unique_ptr<ViewTokenizer> tokenizer;
  std::unique_ptr<PoseEstimator> pose;
  std::unique_ptr<DinoV3> dino;
  std::unique_ptr<CvDrp> cvDrp;
  std::unique_ptr<TokenGating> gating;
  std::unique_ptr<LSegEncoder> lseg;
  std::unique_ptr<SemanticTokens> semantic;
  std::unique_ptr<SceneEncoder> scene;
  std::unique_ptr<Renderer> renderer;
  std::unique_ptr<Sam2Refiner> sam2;
  TransformerWorkspace ws;
  // Device state between encode() and render*().
  Tensor c2w, fxfycxcy, sceneSeq, sceneTokens;
  bool encoded = false;
};

SparPipeline::SparPipeline(Engine& engine, const PackedModel& model, const SparPipelineOptions& options)
    : engine_(engine),
      model_(model),
      options_(options),
      config_(SparConfig::fromJson(model.config(), model.path())),
      weights_(engine, model, options.weightType),
      stages_(std::make_unique<Stages>()),
      watch_(std::make_unique<NonFiniteWatch>(engine)) {
}

SparPipeline::~SparPipeline() = default;

void SparPipeline::keep(const std::string& name, const Tensor& t) {
  if (options_.keepIntermediates && t.defined()) kept_[name] = t;
}

const Tensor& SparPipeline::intermediate(const std::string& name) const {
  auto it = kept_.find(name);
  if (it == kept_.end()) throw Error("no intermediate '" + name + "' (keepIntermediates off, or the stage did not run)");
  return it->second;
}

std::vector<std::string> SparPipeline::intermediateNames() const {
  std::vector<std::string> out;
  for (const auto& [k, v] : kept_) out.push_back(k);
  return out;
}

namespace {
using Clock = std::chrono::steady_clock;
double msSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

// The views `positions` of images [V, 3, H, W] (or masks [V, H, W]: channels 1) as a tensor of their own.
Tensor selectViews(Recorder& rec, const Tensor& all, const std::vector<int64_t>& positions, int64_t perView,
                   const Shape& viewShape) {
  Shape shape{int64_t(positions.size())};
  shape.insert(shape.end(), viewShape.begin(), viewShape.end());
  const Tensor out = rec.engine().tensor(shape);
  for (size_t j = 0; j < positions.size(); ++j)
    copy2d(rec, all.view(positions[j] * perView, {1, perView}), perView, 0, out.view(int64_t(j) * perView, {1, perView}),
           perView, 0, 1, perView);
  return out;
}

}  // namespace

void SparPipeline::addStageTime(const std::string& name, double gpuMs, double wallMs, double buildMs) {
  const uint64_t inUse = engine_.memory().bytesInUse(), peak = engine_.memory().peakBytes();
  auto it = std::find_if(stageTimes_.begin(), stageTimes_.end(), [&](const StageTime& s) { return s.name == name; });
  if (it == stageTimes_.end()) {
    stageTimes_.push_back({name, gpuMs, wallMs, buildMs, inUse, peak});
  } else {
    it->gpuMs += gpuMs;
    it->wallMs += wallMs;
    it->buildMs += buildMs;
    it->deviceBytesAfter = std::max(it->deviceBytesAfter, inUse);
    it->devicePeakBytes = std::max(it->devicePeakBytes, peak);
  }
}

void SparPipeline::addStageTimes(const Recorder& rec, double wallMs) {
  const std::string& name = rec.stage();
  double gpu = 0, build = 0;
  // EngineOptions::profileDispatches (SPAR_PROFILE=1): every dispatch's GPU time on stderr
  // (what a stage spends its time on), and the driver's build before it where there was one.
  const bool profile = engine_.options().profileDispatches;
  for (const DispatchTiming& t : rec.timings()) {
    gpu += t.ms;
    build += t.buildMs;
    if (profile && t.buildMs > 0)
      std::fprintf(stderr, "profile %-16s %-28s %10.3f ms (driver build before it: %.1f ms)\n", name.c_str(),
                   t.label.c_str(), t.ms, t.buildMs);
    else if (profile)
      std::fprintf(stderr, "profile %-16s %-28s %10.3f ms\n", name.c_str(), t.label.c_str(), t.ms);
  }
  addStageTime(name, gpu, wallMs, build);
}


std::string refinementProblem(const PackedModel& model) {
  return model.metadata().count("sam2_config") ? "" : "this model has no SAM2.1 weights (spar-convert --sam2)";
}

std::string imageSizeProblem(const SparConfig& config, int64_t height, int64_t width) {
  const std::string size = std::to_string(height) + "x" + std::to_string(width) + " (HxW)";
  if (height <= 0 || width <= 0 || height % config.patchSize || width % config.patchSize)
    return "image size " + size + " is not a multiple of the model's patch size " + std::to_string(config.patchSize);
  if (config.useLseg && (height % LSegEncoder::kSizeMultiple || width % LSegEncoder::kSizeMultiple))
    return "image size " + size + " is not a multiple of " + std::to_string(LSegEncoder::kSizeMultiple) +
           ", which this model's semantic branch (LSeg) needs";
  return "";
}

const SparEncoded& SparPipeline::encode(const SparRequest& request) {
  Stages& st = *stages_;
  const SparConfig& c = config_;
  request.plan.validate();
  const int64_t h = request.height ? request.height : c.imageHeight;
  const int64_t w = request.width ? request.width : c.imageWidth;
  if (const std::string problem = imageSizeProblem(c, h, w); !problem.empty()) throw Error(problem);
  const int64_t v = request.plan.views, k = int64_t(request.plan.inputs.size()), d = c.d;
  const int64_t gh = h / c.patchSize, gw = w / c.patchSize, n = gh * gw;
  if (int64_t(request.images.size()) != v * 3 * h * w)
    throw Error("expected " + std::to_string(v) + " images of 3x" + std::to_string(h) + "x" + std::to_string(w) +
                " values, got " + std::to_string(request.images.size()) + " values");
  if (request.assumeStatic && request.targetMotion) throw Error("target motion masks need CV-DRP (not --assume-static)");
  if (request.semanticFeatures && !c.semanticDecoding())
    throw Error("this model has no semantic decoding (use_lseg / semantic loss weight): no semantic features");
  const int64_t featureValues = k * c.semanticDim * (h / 2) * (w / 2);
  if (!request.lsegFeatures.empty() && (!c.useLseg || int64_t(request.lsegFeatures.size()) != featureValues))
    throw Error("precomputed LSeg features: expected " + std::to_string(c.useLseg ? featureValues : 0) + " values, got " +
                std::to_string(request.lsegFeatures.size()));
  const bool refine = request.refine || request.maskSource == MaskSource::Refined;
  if (const std::string problem = refine ? refinementProblem(model_) : ""; !problem.empty())
    throw Error(problem + ": no mask refinement");
  if (request.maskSource == MaskSource::Refined && request.assumeStatic)
    throw Error("refined masks gate nothing in a scene declared static (not --assume-static)");
  if (!request.refinePrompts.empty()) {
    if (!refine) throw Error("masks to refine were given without asking for refinement");
    if (int64_t(request.refinePrompts.size()) != v * h * w)
      throw Error("masks to refine: expected " + std::to_string(v) + " masks of " + std::to_string(h) + "x" +
                  std::to_string(w) + " values, got " + std::to_string(request.refinePrompts.size()) + " values");
    for (float p : request.refinePrompts)
      if (!std::isfinite(p)) throw Error("masks to refine hold a value that is not finite");
  } else if (refine && request.assumeStatic) {
    throw Error("refinement needs CV-DRP's masks (not --assume-static) or masks given to refine");
  }
  request_ = request;
  request_.height = h;
  request_.width = w;
  encoded_ = SparEncoded{};
  st.encoded = false;

  if (!st.tokenizer) st.tokenizer = std::make_unique<ViewTokenizer>(engine_, weights_, c);
  Recorder rec(engine_, options_.profile);
  auto finish = [&](const auto t0) { addStageTimes(rec, msSince(t0)); };

  // ---- image tokens (all views) and camera tokens
  const Tensor images = engine_.fromFloats({v, 3, h, w}, request.images);
  const Tensor raw = engine_.tensor({v, n, d}), imgTokens = engine_.tensor({v, n, d});
  const Tensor code = options_.keepIntermediates ? engine_.tensor({v, n, d}) : Tensor();
  const Tensor cam = engine_.tensor({v, d});
  auto t0 = Clock::now();
  rec.setStage("image_tokens");
  st.tokenizer->imageTokens(rec, images, raw, imgTokens, code);
  st.tokenizer->cameraTokens(rec, v, cam);
  watch_->reset();
  watch_->watch(rec, "image_tokens", imgTokens);
  rec.run();
  finish(t0);
  keep("images", images);
  keep("img_tokens_raw", raw);
  keep("pe_code", code);
  keep("img_tokens", imgTokens);
  keep("cam_tokens_in", cam);

  // ---- pose estimator -> cameras
  if (!st.pose) st.pose = std::make_unique<PoseEstimator>(engine_, weights_, c);
  const Tensor enc = engine_.tensor({v + v * n, d});
  st.c2w = engine_.tensor({v, 4, 4});
  st.fxfycxcy = engine_.tensor({v, 4});
  t0 = Clock::now();
  rec.setStage("pose_estimator");
  st.pose->forward(rec, cam, imgTokens, enc, st.c2w, st.fxfycxcy, st.ws);
  watch_->watch(rec, "pose_estimator", st.c2w);
  watch_->watch(rec, "pose_estimator", st.fxfycxcy);
  rec.run();
  finish(t0);
  keep("pose_encoder_out", enc);
  keep("cam_tokens", enc.view(0, {v, d}));
  keep("c2w", st.c2w);
  keep("fxfycxcy", st.fxfycxcy);

  // ---- Plücker rays and ray tokens (all views: CV-DRP sees the targets' too)
  const Tensor rays = engine_.tensor({v, 6, h, w}), rayTokens = engine_.tensor({v, n, d});
  t0 = Clock::now();
  rec.setStage("rays");
  pluckerRays(rec, st.c2w, st.fxfycxcy, rays);
  st.tokenizer->rayTokens(rec, "target_pose_tokenizer", rays, rayTokens);
  watch_->watch(rec, "rays", rayTokens);
  rec.run();
  finish(t0);
  keep("plucker", rays);
  keep("ray_tokens", rayTokens);

  // ---- motion: DINOv3 + CV-DRP (left out for a scene declared static)
  Tensor probInput, probTarget;
  if (!request.assumeStatic) {
    if (!st.dino) st.dino = std::make_unique<DinoV3>(engine_, weights_, c.dino);
    const Tensor dino = engine_.tensor({v, n, d});
    t0 = Clock::now();
    rec.setStage("dino_v3");
    st.dino->forward(rec, images, dino, st.ws);
    watch_->watch(rec, "dino_v3", dino);
    rec.run();
    finish(t0);
    keep("dino", dino);

    if (!st.cvDrp) st.cvDrp = std::make_unique<CvDrp>(engine_, weights_, c);
    t0 = Clock::now();
    rec.setStage("cv_drp");
    const Tensor logitsInput = engine_.tensor({k, 1, h, w});
    probInput = engine_.tensor({k, 1, h, w});
    st.cvDrp->forward(rec, dino, imgTokens, rayTokens, request.plan.inputs, CvDrpMode::Input, gh, gw, logitsInput,
                      probInput, st.ws);
    keep("cv_drp_input.logits", logitsInput);
    keep("cv_drp_input.prob", probInput);
    const int64_t t = int64_t(request.plan.targets.size());
    if (request.targetMotion && t > 0) {
      const Tensor logitsTarget = engine_.tensor({t, 1, h, w});
      probTarget = engine_.tensor({t, 1, h, w});
      st.cvDrp->forward(rec, dino, imgTokens, rayTokens, request.plan.targets, CvDrpMode::Target, gh, gw,
                        logitsTarget, probTarget, st.ws);
      keep("cv_drp_target.logits", logitsTarget);
      keep("cv_drp_target.prob", probTarget);
    }
    watch_->watch(rec, "cv_drp", probInput);
    watch_->watch(rec, "cv_drp", probTarget);
    rec.run();
    finish(t0);
  }

  // ---- SAM2.1 refinement (only when asked: no SAM2 weight is uploaded otherwise)
  Tensor gateMask = probInput;  // what gates the input tokens: CV-DRP's, or the refined masks
  if (refine) {
    const Tensor refinedInput = refineMasks(images, probInput, probTarget);
    if (request.maskSource == MaskSource::Refined) gateMask = refinedInput;
    keep("refined_input", refinedInput);
  }

  // ---- mlp_fuse and gating of the input tokens
  if (!st.gating) st.gating = std::make_unique<TokenGating>(engine_, weights_, c);
  const Tensor fused = engine_.tensor({k * n, d});
  Tensor gated = fused;
  t0 = Clock::now();
  rec.setStage("gating");
  st.gating->fuse(rec, imgTokens, rayTokens, request.plan.inputs, fused);
  // Without gating the fused tokens go on as they are (as with assumeStatic), masks or not.
  if (gateMask.defined() && request.gating) {
    gated = engine_.tensor({k * n, d});
    const Tensor dynPatch = engine_.tensor({k, 1, gh, gw});
    st.gating->gate(rec, fused, gateMask, dynPatch, gated);
    keep("dynamic_patch", dynPatch);
  }
  watch_->watch(rec, "gating", gated);
  rec.run();
  finish(t0);
  keep("fused_tokens", fused);
  keep("gated_tokens", gated);

  // ---- semantic tokens (models with the semantic branch): LSeg features of the inputs with their
  // rays, pooled per 16x16 pixels, projected, gated like the image tokens.
  Tensor gatedSem;
  if (c.useLseg) {
    Tensor features;
    if (!request.lsegFeatures.empty()) {
      features = engine_.fromFloats({k, c.semanticDim, h / 2, w / 2}, request.lsegFeatures);
    } else {
      // LSeg on the input views only (SPAR feeds it the [0, 1] images as they are).
      if (!st.lseg) st.lseg = std::make_unique<LSegEncoder>(engine_, weights_, c);
      features = engine_.tensor({k, c.semanticDim, h / 2, w / 2});
      t0 = Clock::now();
      rec.setStage("lseg");
      const Tensor inputImages = selectViews(rec, images, request.plan.inputs, 3 * h * w, {3, h, w});
      st.lseg->forward(rec, inputImages, features, st.ws);
      watch_->watch(rec, "lseg", features);
      rec.run();
      finish(t0);
    }
    keep("lseg_features", features);
    if (!st.semantic) st.semantic = std::make_unique<SemanticTokens>(engine_, weights_, c);
    const int64_t hs = h / 16, ws = w / 16;
    const Tensor semTokens = engine_.tensor({k * hs * ws, d});
    const Tensor pooled = options_.keepIntermediates ? engine_.tensor({k, c.semanticDim + 6, hs, ws}) : Tensor();
    gatedSem = semTokens;
    t0 = Clock::now();
    rec.setStage("semantic_tokens");
    st.semantic->forward(rec, features, rays, request.plan.inputs, semTokens, pooled);
    if (gateMask.defined() && request.gating) {
      gatedSem = engine_.tensor({k * hs * ws, d});
      const Tensor dynSem = engine_.tensor({k, 1, hs, ws});
      st.gating->gate(rec, semTokens, gateMask, dynSem, gatedSem);
      keep("dynamic_patch_sem", dynSem);
    }
    watch_->watch(rec, "semantic_tokens", gatedSem);
    rec.run();
    finish(t0);
    keep("semantic_in", pooled);
    keep("semantic_tokens", semTokens);
    keep("gated_semantic_tokens", gatedSem);
  }

  // ---- scene encoder
  if (!st.scene) st.scene = std::make_unique<SceneEncoder>(engine_, weights_, c);
  const int64_t rows = c.sceneTokens + k * n + (gatedSem.defined() ? gatedSem.numel() / d : 0);
  st.sceneSeq = engine_.tensor({rows, d});
  const Tensor sceneIn = options_.keepIntermediates ? engine_.tensor({rows, d}) : Tensor();
  t0 = Clock::now();
  rec.setStage("scene_encoder");
  std::vector<Tensor> parts{gated};
  if (gatedSem.defined()) parts.push_back(gatedSem);
  st.scene->forward(rec, parts, st.sceneSeq, st.ws, sceneIn);
  watch_->watch(rec, "scene_encoder", st.sceneSeq);
  rec.run();
  finish(t0);
  st.sceneTokens = st.sceneSeq.view(0, {c.sceneTokens, d});
  keep("scene_encoder_in", sceneIn);
  keep("scene_encoder_out", st.sceneSeq);
  keep("scene_tokens", st.sceneTokens);

  // A NaN or infinity anywhere above is an error naming where it started, not null cameras.
  watch_->check("encoding the views");

  // ---- host copies
  encoded_.c2w = engine_.download(st.c2w);
  encoded_.fxfycxcy = engine_.download(st.fxfycxcy);
  if (probInput.defined()) encoded_.motionInput = engine_.download(probInput);
  if (probTarget.defined()) encoded_.motionTarget = engine_.download(probTarget);
  encoded_.canonicalIndex = c.canonicalIndex(v);
  st.encoded = true;
  return encoded_;
}

// SAM2.1 refinement of the inputs' masks (and the targets' with targetMotion), prompted by
// CV-DRP's P(dynamic) or the request's own masks, on the views' captured images (the official
// _sam2_refine_masks: real target frames, not renders). Fills encoded_'s refined fields and
// returns the inputs' refined masks [K, 1, H, W] on the device.
Tensor SparPipeline::refineMasks(const Tensor& images, const Tensor& probInput, const Tensor& probTarget) {
  Stages& st = *stages_;
  const SparRequest& r = request_;
  const int64_t v = r.plan.views, h = r.height, w = r.width;
  if (!st.sam2)
    st.sam2 = std::make_unique<Sam2Refiner>(engine_, Sam2Config::fromJson(model_.metadata().at("sam2_config")),
                                            sam2Weights(weights_));
  const auto t0 = Clock::now();
  const Tensor given = r.refinePrompts.empty() ? Tensor() : engine_.fromFloats({v, h, w}, r.refinePrompts);
  const auto ran = [this](const Recorder& rec) { addStageTimes(rec, 0.0); };
  const auto refineViews = [&](const std::vector<int64_t>& positions, const Tensor& cvDrp, std::vector<float>& masks) {
    const int64_t count = int64_t(positions.size());
    Recorder rec(engine_);
    const Tensor viewImages = selectViews(rec, images, positions, 3 * h * w, {3, h, w});
    const Tensor prompts = given.defined() ? selectViews(rec, given, positions, h * w, {h, w}) : cvDrp.reshape({count, h, w});
    rec.run();
    Sam2Refined out = st.sam2->refine(viewImages, prompts, options_.profile ? ran : std::function<void(const Recorder&)>());
    masks = std::move(out.masks);
    for (size_t j = 0; j < positions.size(); ++j) {
      const Sam2ViewRefinement& s = out.views[j];
      encoded_.refineViews.push_back({positions[j], s.skipped, s.dynamicPixels, s.iou, s.chosen, s.logits});
    }
  };
  refineViews(r.plan.inputs, probInput, encoded_.refinedInput);
  if (r.targetMotion && !r.plan.targets.empty()) refineViews(r.plan.targets, probTarget, encoded_.refinedTarget);
  addStageTime("sam2_refine", 0.0, msSince(t0), 0.0);  // its GPU time came with each submission (ran)
  return engine_.fromFloats({int64_t(r.plan.inputs.size()), 1, h, w}, encoded_.refinedInput);
}

std::vector<float> SparPipeline::renderRays(const Tensor& c2w, const Tensor& fxfycxcy, int64_t count) {
  Stages& st = *stages_;
  const int64_t h = request_.height, w = request_.width;
  if (!st.renderer) st.renderer = std::make_unique<Renderer>(engine_, weights_, config_, *st.tokenizer);
  Recorder rec(engine_, options_.profile);
  const Tensor rays = engine_.tensor({count, 6, h, w}), rgb = engine_.tensor({count, 3, h, w});
  auto t0 = Clock::now();
  rec.setStage("render_rays");
  pluckerRays(rec, c2w, fxfycxcy, rays);
  watch_->reset();
  watch_->watch(rec, "render_rays", rays);
  rec.run();
  addStageTimes(rec, msSince(t0));
  t0 = Clock::now();
  rec.setStage("renderer");
  RenderTrace trace;
  features_ = request_.semanticFeatures ? engine_.tensor({count, config_.semanticDim, h / 2, w / 2}) : Tensor();
  st.renderer->forward(rec, rays, st.sceneTokens, rgb, st.ws, features_,
                       options_.keepIntermediates ? &trace : nullptr);
  watch_->watch(rec, "renderer", rgb);
  watch_->watch(rec, "renderer", features_);
  rec.run();
  addStageTimes(rec, msSince(t0));
  watch_->check("rendering");
  keep("render_c2w", c2w);
  keep("render_fxfycxcy", fxfycxcy);
  keep("render_plucker", rays);
  keep("rgb_queries", trace.rgbQueries);
  keep("decoder_in", trace.decoderIn);
  keep("decoder_out", trace.decoderOut);
  keep("rgb_tokens", trace.rgbTokens);
  keep("semantic_queries", trace.semanticQueries);
  keep("semantic_out_tokens", trace.semanticOutTokens);
  keep("semantic_hidden", trace.semanticHidden);
  keep("semantic_features", features_);
  keep("rgb", rgb);
  return engine_.download(rgb);
}

std::vector<float> SparPipeline::renderTargets() {
  Stages& st = *stages_;
  if (!st.encoded) throw Error("render before encode");
  const auto& targets = request_.plan.targets;
  const int64_t t = int64_t(targets.size());
  if (t == 0) return {};
  // The targets' estimated cameras, gathered on the device.
  const Tensor c2w = engine_.tensor({t, 4, 4}), k = engine_.tensor({t, 4});
  const auto t0 = Clock::now();
  Recorder rec(engine_, options_.profile);
  rec.setStage("render_rays");
  for (int64_t j = 0; j < t; ++j) {
    copy2d(rec, st.c2w.reshape({request_.plan.views, 16}).view(targets[j] * 16, {1, 16}), 16, 0, c2w.view(j * 16, {1, 16}), 16, 0, 1, 16);
    copy2d(rec, st.fxfycxcy.view(targets[j] * 4, {1, 4}), 4, 0, k.view(j * 4, {1, 4}), 4, 0, 1, 4);
  }
  rec.run();
  addStageTimes(rec, msSince(t0));
  return renderRays(c2w, k, t);
}

std::vector<float> SparPipeline::render(const RenderCameras& cameras) {
  if (!stages_->encoded) throw Error("render before encode");
  const int64_t r = int64_t(cameras.size());
  if (r == 0) return {};
  if (cameras.fxfycxcy.size() != cameras.c2w.size()) throw Error("render cameras: as many intrinsics as poses needed");
  for (int64_t j = 0; j < r; ++j)
    if (const std::string p = renderCameraProblem(cameras.c2w[j], cameras.fxfycxcy[j]); !p.empty())
      throw Error("render camera " + std::to_string(j) + ": " + p);
  std::vector<float> c2w, k;
  for (int64_t j = 0; j < r; ++j) {
    c2w.insert(c2w.end(), cameras.c2w[j].begin(), cameras.c2w[j].end());
    k.insert(k.end(), cameras.fxfycxcy[j].begin(), cameras.fxfycxcy[j].end());
  }
  return renderRays(engine_.fromFloats({r, 4, 4}, c2w), engine_.fromFloats({r, 4}, k), r);
}

}  // namespace spar
