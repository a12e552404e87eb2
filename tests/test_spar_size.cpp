// Image size from the converter to `spar render` / `spar eval` (tools/spar/main.cpp), as a user
// meets it: a tiny SPAR "trained" at 128x128 with a DINOv3 that is not ViT-B, packed with the
// official-format YAML that says 128x128 (tests/python/make_size_model.py), then the built
// `spar` (SPAR_CLI):
//  - without --size it renders at the packed size, 128x128 (view, motion and mask PNGs,
//    cameras.json, report.json's image_size);
//  - --size that is not HxW or not a multiple of the patch size: exit 2, exactly one line
//    "spar: error: ...", no output directory (nor DIR.tmp-*), no result file;
//  - a valid non-square --size renders that size, and the same pixels as the PyTorch
//    reference's `spar-reference render` configured for that size (within 1/255);
//  - spar eval --size evaluates scenes of that size;
//  - imageSizeProblem (model/spar_pipeline.h), the rule both commands apply: multiples of the
//    patch size, and of 32 with the semantic branch.
// Every run of `spar` has the Khronos validation layer with synchronization validation on
// (runValidated) and must print no validation message. The suite is named "spar_size" (`ctest -R spar_size`).
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "imaging/image_prep.h"
#include "model/spar_pipeline.h"
#include "tests/cli_test_support.h"
#include "tests/golden_support.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

const fs::path& scratch() { return scratchDir("spar_size"); }

CommandResult python(const std::vector<std::string>& args) {
  std::vector<std::string> argv{SPAR_PYTHON};
  argv.insert(argv.end(), args.begin(), args.end());
  return runCommand(argv, scratch(), std::string("PYTHONPATH=") + SPAR_PYTHONPATH);
}

// The `spar` binary with the validation layer; its messages would be in stdout or stderr.
CommandResult spar(const std::string& command, std::vector<std::string> args) {
  args.insert(args.begin(), {SPAR_CLI, command});
  return runValidated(args, scratch());
}

// make_size_model.py's model (fixture op_goldens: size/, made once per build): spar.yaml,
// size128.pt, size128.spar, frame_0..2.png.
fs::path fixture() { return opGoldenPath("size"); }
std::string model() { return (fixture() / "size128.spar").string(); }
std::string frame(int i) { return (fixture() / ("frame_" + std::to_string(i) + ".png")).string(); }
std::vector<std::string> views() { return {"--images", frame(0), frame(1), "--targets", frame(2)}; }

json readJson(const fs::path& p) {
  std::ifstream in(p);
  return json::parse(in);
}

void expectPngSize(const fs::path& p, int height, int width) {
  const RgbImage img = loadImageRGB(p.string());
  EXPECT_EQ(img.height, height) << p;
  EXPECT_EQ(img.width, width) << p;
}

// view, motion and mask PNGs, cameras.json and report.json all at height x width.
void expectRenderedAt(const fs::path& out, int height, int width, const std::string& from) {
  for (const char* name : {"view_00.png", "motion_00.png", "motion_01.png", "mask_00.png", "mask_01.png"})
    expectPngSize(out / name, height, width);
  const json cams = readJson(out / "cameras.json");
  EXPECT_EQ(cams["h"], height);
  EXPECT_EQ(cams["w"], width);
  const json size = readJson(out / "report.json")["image_size"];
  EXPECT_EQ(size, json({{"height", height}, {"width", width}, {"from", from}})) << size.dump();
}

// No DIR nor DIR.tmp-* next to where DIR would be.
void expectNothingWritten(const fs::path& out) {
  EXPECT_FALSE(fs::exists(out)) << out;
  const std::string prefix = out.filename().string() + ".tmp";
  for (const auto& e : fs::directory_iterator(out.parent_path()))
    EXPECT_NE(e.path().filename().string().rfind(prefix, 0), 0u) << "left behind: " << e.path();
}

void expectOneLine(const CommandResult& r, int code, const std::string& says, const std::string& name) {
  EXPECT_EQ(r.code, code) << name << ": " << r.err;
  const auto lines = r.errLines();
  ASSERT_EQ(lines.size(), 1u) << name << ": stderr was:\n" << r.err;
  EXPECT_EQ(lines[0].rfind("spar: error: ", 0), 0u) << lines[0];
  EXPECT_NE(lines[0].find(says), std::string::npos) << name << ": " << lines[0];
  std::printf("  %-16s exit %d  %s\n", name.c_str(), r.code, lines[0].c_str());
}

// The bar: a 128x128-trained checkpoint converted with the official YAML renders at
// 128x128 (before, the packed size was 256x256 unless the YAML's DINOv3 was ViT-B).
TEST(spar_size, OfficialYamlModelRendersAtItsTrainingSize) {
  const fs::path out = scratch() / "default";
  const CommandResult r = spar("render", [&] {
    auto a = views();
    a.insert(a.end(), {"--model", model(), "--out", out.string()});
    return a;
  }());
  ASSERT_EQ(r.code, 0) << r.err;
  expectRenderedAt(out, 128, 128, "model");
  EXPECT_NE(r.err.find("at 128x128 (HxW)"), std::string::npos) << r.err;  // the progress line says it
}

TEST(spar_size, BadSizeIsOneLineExit2AndNothingWritten) {
  struct Bad {
    std::string name, size, says;
  };
  const std::vector<Bad> cases = {
      {"not_multiple", "100x100", "image size 100x100 (HxW) is not a multiple of the model's patch size 16"},
      {"width_not_multiple", "128x120", "not a multiple of the model's patch size 16"},
      {"zero", "0x128", "--size must be HxW"},
      {"one_number", "128", "--size must be HxW"},
      {"negative", "-16x16", "--size must be HxW"},
      {"words", "bigxsmall", "--size must be HxW"},
      {"three_sides", "16x16x16", "--size must be HxW"},
  };
  for (const Bad& c : cases) {
    const fs::path out = scratch() / ("out_" + c.name);
    auto args = views();
    args.insert(args.end(), {"--model", model(), "--size", c.size, "--out", out.string()});
    expectOneLine(spar("render", args), 2, c.says, c.name);
    expectNothingWritten(out);
  }
  // spar eval: the same rule, also before any scene is evaluated, and no result file.
  const fs::path scenes = scratch() / "scenes_128";
  const CommandResult g = python({std::string(SPAR_SOURCE_DIR) + "/scenes/spar-scenes", "split", "--split", "test",
                                  "--count", "1", "--size", "128", "--out", scenes.string()});
  ASSERT_EQ(g.code, 0) << g.err;
  for (const Bad& c : {cases[0], cases[3]}) {
    const fs::path out = scratch() / ("eval_" + c.name + ".json");
    expectOneLine(spar("eval", {"--model", model(), "--scenes", scenes.string(), "--views", "2", "--size", c.size,
                                "--out", out.string()}),
                  2, c.says, "eval_" + c.name);
    EXPECT_FALSE(fs::exists(out));
    EXPECT_FALSE(fs::exists(out.string() + ".tmp"));
  }
}

// A valid --size other than the training size, not square: the outputs have that size and the
// engine renders what the PyTorch reference renders with a configuration of that size (the
// sin-cos codes of a non-square grid follow the official code, DINOv3's RoPE and CV-DRP take
// the grid as it is).
TEST(spar_size, ValidSizeRendersThatSizeAsTheReference) {
  const fs::path out = scratch() / "size_64x96", ref = scratch() / "ref_64x96";
  auto args = views();
  args.insert(args.end(), {"--model", model(), "--size", "64x96", "--out", out.string()});
  const CommandResult r = spar("render", args);
  ASSERT_EQ(r.code, 0) << r.err;
  expectRenderedAt(out, 64, 96, "--size");

  const fs::path cfg = scratch() / "cfg_64x96.json";
  const CommandResult c = python(
      {"-c",
       "import sys; from make_size_model import photometric_config\n"
       "c = photometric_config(); c.image_height, c.image_width = 64, 96; c.validate().save(sys.argv[1])",
       cfg.string()});
  ASSERT_EQ(c.code, 0) << c.err;
  auto refArgs = std::vector<std::string>{std::string(SPAR_SOURCE_DIR) + "/reference/spar-reference", "render",
                                          "--checkpoint", (fixture() / "size128.pt").string(), "--config", cfg.string()};
  const auto v = views();
  refArgs.insert(refArgs.end(), v.begin(), v.end());
  refArgs.insert(refArgs.end(), {"--out", ref.string()});
  const CommandResult p = python(refArgs);
  ASSERT_EQ(p.code, 0) << p.err;
  for (const char* name : {"view_00.png", "motion_00.png", "motion_01.png"}) {
    const RgbImage a = loadImageRGB((out / name).string()), b = loadImageRGB((ref / name).string());
    ASSERT_EQ(a.pixels.size(), b.pixels.size()) << name;
    int maxDiff = 0;
    for (size_t i = 0; i < a.pixels.size(); ++i) maxDiff = std::max(maxDiff, std::abs(int(a.pixels[i]) - int(b.pixels[i])));
    EXPECT_LE(maxDiff, 1) << name;
  }
}

// spar eval at a --size: scenes of that size are evaluated (not refused as "does not resize").
TEST(spar_size, EvalAtGivenSize) {
  const fs::path scenes = scratch() / "scenes_64";
  const CommandResult g = python({std::string(SPAR_SOURCE_DIR) + "/scenes/spar-scenes", "split", "--split", "test",
                                  "--count", "1", "--size", "64", "--out", scenes.string()});
  ASSERT_EQ(g.code, 0) << g.err;
  const fs::path out = scratch() / "eval_64.json";
  const std::vector<std::string> base{"--model", model(), "--scenes", scenes.string(), "--views", "2", "--out",
                                      out.string()};
  expectOneLine(spar("eval", base), 1, "does not resize", "eval_default");
  auto sized = base;
  sized.insert(sized.end(), {"--size", "64x64"});
  const CommandResult r = spar("eval", sized);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("at 64x64 (HxW)"), std::string::npos) << r.out;
  EXPECT_EQ(readJson(out)["results"]["2"]["target_views"], 6);
}

// The rule itself: multiples of the patch size; of 32 when LSeg runs (semantic branch).
TEST(spar_size, ImageSizeRule) {
  SparConfig c;  // patch 16
  c.useLseg = false;
  EXPECT_EQ(imageSizeProblem(c, 48, 80), "");
  EXPECT_NE(imageSizeProblem(c, 48, 72).find("not a multiple of the model's patch size 16"), std::string::npos);
  EXPECT_NE(imageSizeProblem(c, 0, 64), "");
  EXPECT_NE(imageSizeProblem(c, -16, 64), "");
  c.useLseg = true;
  EXPECT_EQ(imageSizeProblem(c, 64, 96), "");
  EXPECT_NE(imageSizeProblem(c, 48, 64).find("not a multiple of 32"), std::string::npos);
  EXPECT_NE(imageSizeProblem(c, 64, 80).find("semantic branch (LSeg)"), std::string::npos);
}

}  // namespace
}  // namespace spar::test
