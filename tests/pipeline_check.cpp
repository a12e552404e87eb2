#include "pipeline_check.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>

#include "engine/recorder.h"
#include "text/bpe_tokenizer.h"
#include "model/clip_text.h"
#include "imaging/image_prep.h"
#include "model/label_maps.h"
#include "tests/label_reference.h"
#include "model/stage_tolerances.h"
#include "model/packed_model.h"
#include "test_support.h"

namespace spar::test {
namespace {

// The stages compared, group by group (bounds: model/stage_tolerances.h). Stages are compared
// as the chain runs (each fed by the engine's previous stages).
const std::vector<const char*> kEncodeChecks = {
    "img_tokens_raw", "pe_code", "img_tokens", "cam_tokens_in", "pose_encoder_out", "cam_tokens", "c2w", "fxfycxcy",
    "plucker", "ray_tokens", "fused_tokens", "gated_tokens", "scene_encoder_in", "scene_encoder_out", "scene_tokens",
};
const std::vector<const char*> kMotionChecks = {"dino", "cv_drp_input.logits", "cv_drp_input.prob", "dynamic_patch"};
const std::vector<const char*> kTargetMotionChecks = {"cv_drp_target.logits", "cv_drp_target.prob"};
const std::vector<const char*> kSemanticEncodeChecks = {
    "lseg_features", "semantic_in", "semantic_tokens", "dynamic_patch_sem", "gated_semantic_tokens",
};
const std::vector<const char*> kSemanticRenderChecks = {
    "semantic_queries", "semantic_out_tokens", "semantic_hidden", "semantic_features",
};
const std::vector<const char*> kRenderChecks = {
    "render_c2w", "render_fxfycxcy", "render_plucker", "rgb_queries", "decoder_in", "decoder_out", "rgb_tokens", "rgb",
};

void expectStage(Engine& engine, const SparPipeline& pipe, const GoldenCase& g, const char* name,
                 const CaseOptions& o) {
  const auto own = o.thresholds.find(name);
  const double maxNmse = (own == o.thresholds.end() ? fp32StageNmseBound(name) : own->second) * o.scale;
  SCOPED_TRACE(name);
  ASSERT_TRUE(g.has(name)) << "no golden " << name;
  const std::vector<double> want = g.doubles(name);
  const std::vector<float> got = engine.download(pipe.intermediate(name));
  ASSERT_EQ(got.size(), want.size()) << name;
  const ErrorStats e = compare(got, want);
  std::printf("  %-22s NMSE %.3e  max abs %.3e\n", name, e.nmse, e.maxAbs);
  EXPECT_EQ(e.nonFinite, 0u) << name;
  EXPECT_LE(e.nmse, maxNmse) << name;
}

// The binary motion mask: identical except where the reference probability is within tieBand
// of the threshold (a near-tie either side may round either way).
void expectMask(Engine& engine, const SparPipeline& pipe, const GoldenCase& g, const std::string& prefix,
                float threshold, double tieBand) {
  const std::vector<float> prob = engine.download(pipe.intermediate(prefix + ".prob"));
  const std::vector<double> want = g.doubles(prefix + ".prob");
  const std::vector<double> binary = g.doubles(prefix + ".binary");
  ASSERT_EQ(prob.size(), binary.size());
  size_t differ = 0, ties = 0;
  for (size_t i = 0; i < prob.size(); ++i) {
    const bool mine = prob[i] > threshold, theirs = binary[i] != 0.0;
    if (mine == theirs) continue;
    if (std::abs(want[i] - threshold) < tieBand) ++ties;
    else ++differ;
  }
  std::printf("  %-22s mask pixels differing %zu (+%zu near-ties of %zu)\n", (prefix + ".binary").c_str(), differ,
              ties, prob.size());
  EXPECT_EQ(differ, 0u) << prefix;
}

}  // namespace

std::vector<float> prepareFrames(const GoldenCase& g, int64_t h, int64_t w) {
  std::vector<float> all;
  for (const std::string& f : g.files()) {
    std::vector<float> one = loadPreparedImage(f, int(h), int(w));
    all.insert(all.end(), one.begin(), one.end());
  }
  return all;
}

std::vector<StageTime> runGoldenCase(Engine& engine, const std::string& caseName, const CaseOptions& o) {
  GoldenCase g(caseName);
  PackedModel model = PackedModel::open(o.model.empty() ? tinyModelPath() : o.model);
  SparPipeline pipe(engine, model, {.profile = true, .keepIntermediates = true, .weightType = o.weightType});
  const SparConfig& c = pipe.config();
  SparRequest req;
  req.images = prepareFrames(g, c.imageHeight, c.imageWidth);
  req.plan.views = int64_t(g.files().size());
  req.plan.inputs = g.inputs();
  req.plan.targets = g.targets();
  req.assumeStatic = o.assumeStatic;
  req.targetMotion = o.targetMotion && !o.assumeStatic && !req.plan.targets.empty();
  // The prepared images are bit-exact with the reference's (x / 255 rounded to float).
  const std::vector<double> images = g.doubles("images");
  EXPECT_EQ(images.size(), req.images.size());
  size_t differ = 0;
  for (size_t i = 0; i < std::min(images.size(), req.images.size()); ++i) differ += req.images[i] != float(images[i]);
  EXPECT_EQ(differ, 0u) << "prepared images";

  if (o.semantic) {
    req.semanticFeatures = true;
    if (o.goldenLseg) req.lsegFeatures = g.floats("lseg_features");
  }
  pipe.encode(req);
  for (const char* s : kEncodeChecks) expectStage(engine, pipe, g, s, o);
  if (o.semantic) {
    for (const char* s : kSemanticEncodeChecks) {
      if (o.assumeStatic && std::string(s) == "dynamic_patch_sem") continue;
      expectStage(engine, pipe, g, s, o);
    }
  }
  if (!o.assumeStatic) {
    for (const char* s : kMotionChecks) expectStage(engine, pipe, g, s, o);
    expectMask(engine, pipe, g, "cv_drp_input", c.maskThreshold, o.maskTieBand);
    if (req.targetMotion) {
      for (const char* s : kTargetMotionChecks) expectStage(engine, pipe, g, s, o);
      expectMask(engine, pipe, g, "cv_drp_target", c.maskThreshold, o.maskTieBand);
    }
  }
  if (o.pathCameras) {
    RenderCameras cams;
    const std::vector<float> c2w = g.floats("render_c2w"), k = g.floats("render_fxfycxcy");
    for (size_t j = 0; j < k.size() / 4; ++j) {
      std::array<float, 16> m;
      std::array<float, 4> kk;
      std::copy_n(c2w.begin() + j * 16, 16, m.begin());
      std::copy_n(k.begin() + j * 4, 4, kk.begin());
      cams.c2w.push_back(m);
      cams.fxfycxcy.push_back(kk);
    }
    pipe.render(cams);
  } else {
    pipe.renderTargets();
  }
  for (const char* s : kRenderChecks) expectStage(engine, pipe, g, s, o);
  if (o.semantic)
    for (const char* s : kSemanticRenderChecks) expectStage(engine, pipe, g, s, o);
  for (const StageTime& t : pipe.stageTimes()) {
    EXPECT_GE(t.gpuMs, 0.0) << t.name;
    if (o.assumeStatic) {
      EXPECT_TRUE(t.name != "dino_v3" && t.name != "cv_drp") << t.name << " ran for a static scene";
    }
  }
  // Open-vocabulary labels when the golden has them: the prompts through the engine's tokenizer
  // and CLIP text encoder, label maps from the engine's semantic features.
  if (o.semantic && g.has("text_embeddings") && g.has("label_maps")) {
    std::vector<std::string> prompts = g.manifest().at("labels").get<std::vector<std::string>>();
    const std::vector<int32_t> ids = BpeTokenizer::fromModel(model).tokenize(prompts);
    const std::vector<double> wantIds = g.doubles("text_tokens");
    size_t idDiff = 0;
    for (size_t i = 0; i < ids.size(); ++i) idDiff += double(ids[i]) != wantIds[i];
    EXPECT_EQ(idDiff, 0u) << "text token ids";
    WeightSet textWeights(engine, model, o.weightType);
    ClipTextEncoder encoder(engine, textWeights, ClipTextConfig::fromJson(c.raw.at("clip"), model.path()));
    const Tensor text = engine.tensor({int64_t(prompts.size()), encoder.config().embedDim});
    const Tensor& feats = pipe.intermediate("semantic_features");
    const Tensor maps = engine.tensor({feats.dim(0), 2 * feats.dim(2), 2 * feats.dim(3)}, DType::I32);
    TransformerWorkspace ws;
    Recorder rec(engine);
    encoder.forward(rec, ids, text, ws);
    labelMaps(rec, feats, text, maps);
    rec.run();
    const ErrorStats e = compare(engine.download(text), g.doubles("text_embeddings"));
    std::printf("  %-22s NMSE %.3e  max abs %.3e\n", "text_embeddings", e.nmse, e.maxAbs);
    EXPECT_LE(e.nmse, 1e-10 * o.scale) << "text_embeddings";
    std::vector<int32_t> got(size_t(maps.numel()));
    engine.read(maps, got.data(), got.size() * sizeof(int32_t));
    // at the image's size: the reference's logits x2 (float64) say where two labels nearly tie
    const std::vector<double> want = g.doubles("label_maps");
    const size_t p = prompts.size(), plane = size_t(4 * feats.dim(2) * feats.dim(3));
    const std::vector<double> scores =
        upsampledLogits(g.doubles("label_logits"), feats.dim(0), int64_t(p), feats.dim(2), feats.dim(3));
    EXPECT_EQ(want.size(), got.size()) << "label_maps: the reference's are not at the image's size";
    size_t differ = 0, ties = 0;
    for (size_t i = 0; i < got.size() && i < want.size(); ++i) {
      if (double(got[i]) == want[i]) continue;
      // a near-tie: the reference's scores of the two labels within kLabelTieGap
      const size_t r = i / plane, px = i % plane;
      const double a = scores[(r * p + size_t(got[i])) * plane + px], b = scores[(r * p + size_t(want[i])) * plane + px];
      if (std::abs(a - b) < kLabelTieGap) ++ties;
      else ++differ;
    }
    std::printf("  %-22s pixels differing %zu (+%zu near-ties of %zu)\n", "label_maps", differ, ties, got.size());
    EXPECT_EQ(differ, 0u) << "label_maps";
  }
  return pipe.stageTimes();
}

// NMSE thresholds of the fp16-weight pipeline against float64, per stage. Measured on the tiny
// perturbed model, largest over the interleaved, odd_targets, static, path and --fp16-pack cases
// (NMSE, max abs in the comment); thresholds are 10x the NMSE, or the fp32 threshold
// (tests/pipeline_check.cpp, 1e-10) where that is larger. Rounding a weight to fp16 is a relative
// error up to 2^-11 (NMSE ~ 1e-7 on one product); the token stages carry 4e-8 of it, while the
// cameras (from a 9- and a 1-row head on pooled tokens), the CV-DRP logits (dominated by the
// decoder's bias) and rgb (after the sigmoid) barely see it. pe_code reads no weight: fp32 check.
const std::map<std::string, double>& fp16WeightThresholds() {
  static const std::map<std::string, double> table = {
    {"img_tokens_raw", 5e-7},        // 4.1e-8, max abs 3.4e-4
    {"img_tokens", 4e-7},            // 3.6e-8, 3.4e-4
    {"cam_tokens_in", 1e-8},         // 9.9e-10, 6.8e-6
    {"pose_encoder_out", 4e-7},      // 3.6e-8, 3.4e-4
    {"cam_tokens", 4e-8},            // 3.2e-9, 1.2e-5
    {"c2w", 1e-10},                  // 9.6e-12, 4.0e-6
    {"fxfycxcy", 1e-10},             // 2.0e-12, 2.0e-6
    {"plucker", 2e-10},              // 1.1e-11, 4.2e-6
    {"ray_tokens", 4e-7},            // 3.9e-8, 2.0e-4
    {"dino", 9e-7},                  // 8.3e-8, 1.7e-3
    {"cv_drp_input.logits", 1e-10},  // 6.7e-12, 3.7e-6
    {"cv_drp_input.prob", 1e-10},    // 1.4e-12, 8.2e-7
    {"dynamic_patch", 1e-10},        // 1.5e-12, 5.7e-7
    {"cv_drp_target.logits", 1e-10}, // 6.7e-12, 3.7e-6
    {"cv_drp_target.prob", 1e-10},   // 1.4e-12, 8.2e-7
    {"fused_tokens", 4e-8},          // 3.7e-9, 2.5e-5
    {"gated_tokens", 4e-8},          // 3.7e-9, 2.5e-5
    {"scene_encoder_in", 4e-8},      // 3.7e-9, 2.5e-5
    {"scene_encoder_out", 7e-8},     // 6.7e-9, 3.4e-5
    {"scene_tokens", 5e-7},          // 4.0e-8, 1.9e-5
    {"render_c2w", 2e-10},           // 1.2e-11, 4.0e-6
    {"render_fxfycxcy", 1e-10},      // 1.9e-12, 1.9e-6
    {"render_plucker", 2e-10},       // 1.4e-11, 4.2e-6
    {"rgb_queries", 4e-7},           // 3.8e-8, 2.2e-4
    {"decoder_in", 5e-7},            // 4.2e-8, 7.6e-4
    {"decoder_out", 5e-7},           // 4.2e-8, 7.5e-4
    {"rgb_tokens", 5e-7},            // 4.2e-8, 7.5e-4
    {"rgb", 6e-9},                   // 5.1e-10, 4.7e-5
};
  return table;
}

}  // namespace spar::test
