// The refinement inside a request (model/spar_pipeline: Request::refine, maskSource,
// refinePrompts) on the tiny model packed with this variant (fixture spar_goldens,
// tiny_sam2.spar): the refiner's own result on the request's views, the gating it feeds, what is
// left out without it, and the one-line refusals.
//
// model/sam2_image_encoder (SAM2.1's image encoder: pre-processing, patch embedding, position
// table, the Hiera blocks, the FPN neck, conv_s0 / conv_s1, no_mem_embed) and
// model/sam2_mask_decoder (mask prompt, dense prompt, two-way transformer, upscaling,
// hypernetworks, IoU, the chosen mask's logits) against the PyTorch
// reference in float64 (tests/python/make_sam2_encoder_golden.py, fixture op_goldens), stage by
// stage, on a tiny variant whose schedule crosses q pooling, a global block over 4096 tokens,
// padded windows of 6 pooled to 3 and padded windows of 3. Model/sam2_config's parse of the
// variant is checked against the converter's block schedule on the way.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "formats/npy.h"
#include "model/sam2_config.h"
#include "model/sam2_image_encoder.h"
#include "model/sam2_mask_decoder.h"
#include "model/sam2_refinement.h"
#include "model/spar_pipeline.h"
#include "tests/golden_support.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;

std::string dir() { return opGoldenPath("sam2_path"); }

std::string readText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

class Sam2ImageEncoderTest : public EngineTest {};

TEST_F(Sam2ImageEncoderTest, MatchesReferenceStageByStage) {
  const Sam2Config c = Sam2Config::fromJson(readText(dir() + "/config.json"));
  const std::vector<Sam2BlockSpec> blocks = c.blocks();
  ASSERT_EQ(blocks.size(), 6u);
  EXPECT_TRUE(blocks[1].qPool && blocks[2].qPool && blocks[4].qPool && !blocks[3].qPool);
  EXPECT_EQ(blocks[3].window, 0);  // global
  EXPECT_EQ(blocks[4].window, 6);  // the window lags a block
  EXPECT_EQ(blocks[5].window, 3);
  EXPECT_EQ(blocks[5].heads, 8);

  WeightLookup weights = [this](const std::string& key) -> Tensor {
    const fs::path p = fs::path(dir()) / "weights" / (key.substr(std::string("sam2.").size()) + ".npy");
    if (!fs::exists(p)) return Tensor();
    const NpyArray a = readNpy(p.string());
    return eng().fromFloats(a.shape, a.toFloats());
  };
  const Sam2ImageEncoder encoder(eng(), c, weights);
  const NpyArray images = readNpy(dir() + "/images.npy");
  const Tensor timages = eng().fromFloats(images.shape, images.toFloats());
  Recorder rec(eng());
  const Sam2ImageFeatures f = encoder.encode(rec, timages, 1);
  rec.run();
  // fp32 against float64 through 6 blocks (LayerNorms, attention over up to 4096 keys, GEMMs)
  // and the neck: measured NMSE 1e-13 .. 1e-12; thresholds those of the model-level stages
  // (model/stage_tolerances.cpp) for a stack this deep.
  for (int i = 0; i < 4; ++i) {
    const NpyArray s = readNpy(dir() + "/stage_" + std::to_string(i) + ".npy");
    ASSERT_EQ(s.shape, f.stages[size_t(i)].shape()) << "stage " << i;
    expectClose(eng().download(f.stages[size_t(i)]), s.toDoubles(), 1e-10, 1e-4, "stage " + std::to_string(i));
  }
  const std::pair<const char*, Tensor> outs[] = {{"image_embed", f.imageEmbed}, {"feat_s0", f.featS0}, {"feat_s1", f.featS1}};
  for (const auto& [name, t] : outs) {
    const NpyArray g = readNpy(dir() + "/" + name + ".npy");
    ASSERT_EQ(g.shape, t.shape()) << name;
    expectClose(eng().download(t), g.toDoubles(), 1e-10, 1e-4, name);
  }

  // the decoder on those features, prompted by view 1's P(dynamic) (48 x 40 -> 256 x 256)
  const Sam2MaskDecoder decoder(eng(), c, weights);
  const NpyArray probs = readNpy(dir() + "/probs.npy");
  Recorder rec2(eng());
  const Sam2MaskResult m = decoder.decode(rec2, f, eng().fromFloats(probs.shape, probs.toFloats()), 1, true);
  rec2.run();
  const std::pair<const char*, Tensor> decoded[] = {{"prompt", m.prompt},       {"dense", m.dense},
                                                    {"tokens_out", m.tokensOut}, {"upscaled", m.upscaled},
                                                    {"low_res_logits", m.allLogits}, {"iou", m.iou},
                                                    {"chosen_logits", m.chosenLogits}};
  for (const auto& [name, t] : decoded) {
    const NpyArray g = readNpy(dir() + "/" + name + ".npy");
    ASSERT_EQ(g.shape, t.shape()) << name;
    expectClose(eng().download(t), g.toDoubles(), 1e-10, 1e-4, name);
  }
}

// The whole refinement of 3 views (a blob; nothing dynamic; exactly 10 dynamic pixels) against
// the reference's refine_masks: the skip rule, the IoU scores (bar: 1e-5), the chosen mask, and
// the refined masks pixel by pixel (bar: at most 0.1 % differ, only where the logit is within
// 1e-4 of 0).
TEST_F(Sam2ImageEncoderTest, RefinesLikeTheReference) {
  const std::string d = dir() + "/refine";
  const Sam2Config c = Sam2Config::fromJson(readText(dir() + "/config.json"));
  WeightLookup weights = [this](const std::string& key) -> Tensor {
    const fs::path p = fs::path(dir()) / "weights" / (key.substr(std::string("sam2.").size()) + ".npy");
    if (!fs::exists(p)) return Tensor();
    const NpyArray a = readNpy(p.string());
    return eng().fromFloats(a.shape, a.toFloats());
  };
  Sam2Refiner refiner(eng(), c, weights);
  const NpyArray images = readNpy(d + "/images.npy"), probs = readNpy(d + "/probs.npy");
  const Sam2Refined r = refiner.refine(eng().fromFloats(images.shape, images.toFloats()),
                                       eng().fromFloats(probs.shape, probs.toFloats()));
  const nlohmann::json summary = nlohmann::json::parse(readText(d + "/summary.json"));
  const std::vector<double> refined = readNpy(d + "/refined.npy").toDoubles(), logits = readNpy(d + "/logits.npy").toDoubles();
  ASSERT_EQ(r.views.size(), 3u);
  ASSERT_EQ(r.masks.size(), refined.size());
  const size_t hw = refined.size() / 3;
  for (size_t v = 0; v < 3; ++v) {
    const auto& want = summary[v];
    EXPECT_EQ(r.views[v].skipped, want["skipped"].get<bool>()) << v;
    EXPECT_EQ(r.views[v].dynamicPixels, want["dynamic_pixels"].get<int64_t>()) << v;
    if (!r.views[v].skipped) {
      EXPECT_EQ(r.views[v].chosen, want["chosen"].get<int>()) << v;
      for (size_t i = 0; i < 3; ++i) EXPECT_NEAR(r.views[v].iou[i], want["iou"][i].get<double>(), 1e-5) << v;
      EXPECT_EQ(r.views[v].logits.size(), size_t(256 * 256));
    }
    size_t differ = 0;
    for (size_t i = v * hw; i < (v + 1) * hw; ++i)
      if (double(r.masks[i]) != refined[i]) {
        ++differ;
        EXPECT_LT(std::abs(logits[i]), 1e-4) << "view " << v << " pixel " << i - v * hw;
      }
    std::printf("  refined view %zu: %s, %zu of %zu pixels differ from the reference\n", v,
                r.views[v].skipped ? "skipped" : "refined", differ, hw);
    EXPECT_LE(double(differ), 0.001 * double(hw)) << "view " << v;
  }
  EXPECT_TRUE(r.views[1].skipped);
  EXPECT_FALSE(r.views[2].skipped);  // 10 dynamic pixels: the skip rule's edge, refined
}

// --- the refinement inside a request ------------------------------------------------------

constexpr int64_t kSide = 128;  // the tiny model's image size

const PackedModel& tinySam2() {
  static const PackedModel m = PackedModel::open(goldenPath("tiny_sam2.spar"));
  return m;
}

// 3 views (inputs 0 and 2, target 1) of random images.
SparRequest threeViews() {
  SparRequest r;
  r.images = randomUniform(size_t(3 * 3 * kSide * kSide), 0.0f, 1.0f, 91);
  r.plan = {3, {0, 2}, {1}};
  return r;
}

// The caller's masks: a disc in view 0 and in view 1 (refined), nothing in view 2 (skipped).
std::vector<float> discPrompts() {
  std::vector<float> p(size_t(3 * kSide * kSide), 0.0f);
  for (int64_t v : {0, 1})
    for (int64_t y = 0; y < kSide; ++y)
      for (int64_t x = 0; x < kSide; ++x) {
        const double dy = double(y) - 50.0 - 20.0 * double(v), dx = double(x) - 60.0;
        p[size_t((v * kSide + y) * kSide + x)] = dy * dy + dx * dx < 30.0 * 30.0 ? 0.9f : 0.1f;
      }
  return p;
}

// rows [positions] of a [V, per] array
std::vector<float> rowsOf(const std::vector<float>& all, const std::vector<int64_t>& positions, size_t per) {
  std::vector<float> out;
  for (int64_t v : positions) out.insert(out.end(), all.begin() + long(size_t(v) * per), all.begin() + long(size_t(v + 1) * per));
  return out;
}

// 16 x 16 means of masks [K, H, W] (the gating's pooled map).
std::vector<double> patchMeans(const std::vector<float>& masks, int64_t k) {
  const int64_t g = kSide / 16;
  std::vector<double> out(size_t(k * g * g), 0.0);
  for (int64_t v = 0; v < k; ++v)
    for (int64_t y = 0; y < kSide; ++y)
      for (int64_t x = 0; x < kSide; ++x)
        out[size_t((v * g + y / 16) * g + x / 16)] += double(masks[size_t((v * kSide + y) * kSide + x)]) / 256.0;
  return out;
}

class Sam2RequestTest : public EngineTest {};
class Sam2RequestPrecision : public EngineTest, public ::testing::WithParamInterface<DType> {};

// fp32 weights, and fp16 (SAM2's matrices rounded as the rest of the model's: the refiner alone
// with the same weight set gives the same bits).
TEST_P(Sam2RequestPrecision, RefinedMasksAreSam2OnTheRequestsOwnViews) {
  const DType weightType = GetParam();
  if (weightType == DType::F16 && !eng().readsFp16Inputs()) GTEST_SKIP() << "device without fp16 inputs";
  SparPipelineOptions o;
  o.weightType = weightType;
  SparPipeline pipeline(eng(), tinySam2(), o);
  SparRequest r = threeViews();
  r.refine = true;
  r.targetMotion = true;
  r.refinePrompts = discPrompts();
  const SparEncoded e = pipeline.encode(r);
  const size_t plane = size_t(kSide * kSide);
  ASSERT_EQ(e.refinedInput.size(), 2 * plane);
  ASSERT_EQ(e.refinedTarget.size(), plane);
  ASSERT_EQ(e.refineViews.size(), 3u);
  EXPECT_EQ(e.refineViews[0].view, 0);
  EXPECT_EQ(e.refineViews[1].view, 2);
  EXPECT_EQ(e.refineViews[2].view, 1);  // inputs first, then targets
  EXPECT_FALSE(e.refineViews[0].skipped);
  EXPECT_TRUE(e.refineViews[1].skipped);
  EXPECT_FALSE(e.refineViews[2].skipped);
  for (float m : e.refinedInput) ASSERT_TRUE(m == 0.0f || m == 1.0f);
  EXPECT_EQ(std::count(e.refinedInput.begin() + long(plane), e.refinedInput.end(), 1.0f), 0);  // skipped: its 0.1s
  EXPECT_EQ(e.motionInput.size(), 2 * plane);  // CV-DRP still ran: its masks are reported as ever

  // The refiner by itself on the same views and masks: the same result, bit for bit.
  WeightSet weights(eng(), tinySam2(), weightType);
  Sam2Refiner direct(eng(), Sam2Config::fromJson(tinySam2().metadata().at("sam2_config")), sam2Weights(weights));
  const std::pair<std::vector<int64_t>, const std::vector<float>*> sets[] = {{{0, 2}, &e.refinedInput},
                                                                           {{1}, &e.refinedTarget}};
  size_t at = 0;
  for (const auto& [positions, got] : sets) {
    const int64_t n = int64_t(positions.size());
    const Sam2Refined want =
        direct.refine(eng().fromFloats({n, 3, kSide, kSide}, rowsOf(r.images, positions, 3 * plane)),
                      eng().fromFloats({n, kSide, kSide}, rowsOf(r.refinePrompts, positions, plane)));
    EXPECT_EQ(*got, want.masks);
    for (const Sam2ViewRefinement& w : want.views) {
      const RefinedView& g = e.refineViews[at++];
      EXPECT_EQ(g.skipped, w.skipped);
      EXPECT_EQ(g.dynamicPixels, w.dynamicPixels);
      EXPECT_EQ(g.chosen, w.chosen);
      EXPECT_EQ(g.iou, w.iou);
      EXPECT_EQ(g.logits, w.logits);
    }
  }
  bool timed = false;
  for (const StageTime& t : pipeline.stageTimes()) timed = timed || (t.name == "sam2_refine" && t.gpuMs > 0);
  EXPECT_TRUE(timed);
}
INSTANTIATE_TEST_SUITE_P(Weights, Sam2RequestPrecision, ::testing::Values(DType::F32, DType::F16),
                         [](const auto& info) { return std::string(info.param == DType::F16 ? "fp16" : "fp32"); });

// mask_source: raw gates with CV-DRP's probabilities, refined with the refined masks (each
// 16 x 16 averaged per token), and the tokens differ where the masks do.
TEST_F(Sam2RequestTest, MaskSourceChoosesWhatGatesTheTokens) {
  SparPipelineOptions o;
  o.keepIntermediates = true;
  SparRequest r = threeViews();
  r.refinePrompts = discPrompts();
  r.refine = true;
  SparPipeline raw(eng(), tinySam2(), o);
  const SparEncoded a = raw.encode(r);
  r.refine = false;
  r.maskSource = MaskSource::Refined;  // implies the refinement
  SparPipeline refined(eng(), tinySam2(), o);
  const SparEncoded b = refined.encode(r);
  EXPECT_EQ(a.refinedInput, b.refinedInput);
  EXPECT_EQ(a.motionInput, b.motionInput);
  expectClose(eng().download(raw.intermediate("dynamic_patch")), patchMeans(a.motionInput, 2), 1e-12, 1e-6, "raw");
  expectClose(eng().download(refined.intermediate("dynamic_patch")), patchMeans(b.refinedInput, 2), 1e-12, 1e-6,
              "refined");
  EXPECT_NE(eng().download(raw.intermediate("gated_tokens")), eng().download(refined.intermediate("gated_tokens")));
}

// Without refine: no SAM2 weight on the device, no SAM2 stage, nothing refined.
TEST_F(Sam2RequestTest, NothingOfSam2WithoutRefine) {
  SparPipeline pipeline(eng(), tinySam2());
  const SparEncoded e = pipeline.encode(threeViews());
  EXPECT_TRUE(e.refinedInput.empty() && e.refinedTarget.empty() && e.refineViews.empty());
  for (const auto& [name, dtype] : pipeline.weights().loaded()) EXPECT_NE(name.rfind("sam2.", 0), 0u) << name;
  for (const StageTime& t : pipeline.stageTimes()) EXPECT_NE(t.name, "sam2_refine");
}

TEST_F(Sam2RequestTest, RefusesWhatCannotBeRefined) {
  auto refusal = [&](const PackedModel& m, const SparRequest& r) -> std::string {
    SparPipeline pipeline(eng(), m);
    try {
      pipeline.encode(r);
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  };
  const PackedModel plain = PackedModel::open(tinyModelPath());
  SparRequest r = threeViews();
  r.refine = true;
  EXPECT_NE(refusal(plain, r).find("no SAM2.1 weights"), std::string::npos);
  SparRequest staticScene = threeViews();
  staticScene.assumeStatic = true;
  staticScene.maskSource = MaskSource::Refined;
  EXPECT_NE(refusal(tinySam2(), staticScene).find("not --assume-static"), std::string::npos);
  staticScene.maskSource = MaskSource::Raw;
  staticScene.refine = true;
  EXPECT_NE(refusal(tinySam2(), staticScene).find("CV-DRP's masks"), std::string::npos);
  SparRequest prompts = threeViews();
  prompts.refinePrompts = discPrompts();
  EXPECT_NE(refusal(tinySam2(), prompts).find("without asking for refinement"), std::string::npos);
  prompts.refine = true;
  prompts.refinePrompts.pop_back();
  EXPECT_NE(refusal(tinySam2(), prompts).find("expected 3 masks of 128x128"), std::string::npos);
  prompts.refinePrompts = discPrompts();
  prompts.refinePrompts[7] = std::nanf("");
  EXPECT_NE(refusal(tinySam2(), prompts).find("not finite"), std::string::npos);
}

TEST_F(Sam2ImageEncoderTest, ConfigRefusesWhatTheConverterRefuses) {
  const std::string ok = readText(dir() + "/config.json");
  EXPECT_NO_THROW(Sam2Config::fromJson(ok));
  EXPECT_THROW(Sam2Config::fromJson("{"), Error);
  EXPECT_THROW(Sam2Config::fromJson(R"({"embed_dim": 8})"), Error);
  std::string badChannels = ok;
  badChannels.replace(badChannels.find("[64, 32, 16, 8]"), 15, "[64, 32, 16, 9]");
  EXPECT_THROW(Sam2Config::fromJson(badChannels), Error);
  // The image side: the official 1024, also where a file packed before it was recorded has none;
  // the maps and the mask prompt follow a smaller one (the test models' 256).
  EXPECT_EQ(Sam2Config::fromJson(ok).imageSize, 1024);
  std::string noSize = ok;
  noSize.replace(noSize.find(", \"image_size\": 1024"), 20, "");
  EXPECT_EQ(Sam2Config::fromJson(noSize).imageSize, 1024);
  std::string quarter = ok;
  quarter.replace(quarter.find("\"image_size\": 1024"), 18, "\"image_size\": 256");
  const Sam2Config q = Sam2Config::fromJson(quarter);
  EXPECT_EQ(std::vector<int64_t>({q.tokenSide(), q.maskInputSize()}), std::vector<int64_t>({64, 64}));
  // Sizes no variant has, which would overflow the widths' doublings or make schedules of
  // billions of blocks: refused in one line (the fuzzer's invariants, tests/fuzz).
  auto with = [&](const std::string& from, const std::string& to) {
    std::string t = ok;
    const size_t at = t.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    return t.replace(at, from.size(), to);
  };
  for (const auto& [from, to] : std::vector<std::pair<std::string, std::string>>{
           {"\"stages\": [1, 1, 2, 2]", "\"stages\": [1, 1, 2000000000, 2]"},
           {"\"embed_dim\": 8", "\"embed_dim\": 4611686018427387904"},
           {"\"window_spec\": [8, 4, 6, 3]", "\"window_spec\": [8, 4, 6, 300]"},
           {"\"image_size\": 1024", "\"image_size\": 1000"},   // not four stages of 2x
           {"\"image_size\": 1024", "\"image_size\": 4096"},   // past the limit
           {"\"image_size\": 1024", "\"image_size\": 32"}}) {  // windows of 8 on an 8-token map

    try {
      Sam2Config::fromJson(with(from, to));
      ADD_FAILURE() << to << " accepted";
    } catch (const Error& e) {
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("sam2_config: "), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace spar::test
