// model/sam2_image_encoder (SAM2.1's image encoder: pre-processing, patch embedding, position
// table, the Hiera blocks, the FPN neck, conv_s0 / conv_s1, no_mem_embed) and
// model/sam2_mask_decoder (mask prompt, dense prompt, two-way transformer, upscaling,
// hypernetworks, IoU, the chosen mask's logits) against the PyTorch
// reference in float64 (tests/python/make_sam2_encoder_golden.py, fixture op_goldens), stage by
// stage, on a tiny variant whose schedule crosses q pooling, a global block over 4096 tokens,
// padded windows of 6 pooled to 3 and padded windows of 3. Model/sam2_config's parse of the
// variant is checked against the converter's block schedule on the way.
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

TEST_F(Sam2ImageEncoderTest, ConfigRefusesWhatTheConverterRefuses) {
  const std::string ok = readText(dir() + "/config.json");
  EXPECT_NO_THROW(Sam2Config::fromJson(ok));
  EXPECT_THROW(Sam2Config::fromJson("{"), Error);
  EXPECT_THROW(Sam2Config::fromJson(R"({"embed_dim": 8})"), Error);
  std::string badChannels = ok;
  badChannels.replace(badChannels.find("[64, 32, 16, 8]"), 15, "[64, 32, 16, 9]");
  EXPECT_THROW(Sam2Config::fromJson(badChannels), Error);
}

}  // namespace
}  // namespace spar::test
