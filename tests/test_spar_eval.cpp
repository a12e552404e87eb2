// `spar eval` (tools/spar/eval_command.*) as a user runs it: the built binary (SPAR_CLI)
// on two test scenes made by `scenes/spar-scenes split --split test --count 2 --size 128`,
// with the tiny semantic model of the spar_goldens_semantic fixture (128x128).
//  - The three modes for --views 2,3: result.json has the protocol's fields (PROTOCOL.md,
//    "Output JSON"), numbers finite and in range, mask metrics null only with --assume-static,
//    --no-gating and --assume-static render the same (identical PSNR / SSIM / semantics), and
//    the default and --no-gating runs share CV-DRP (identical mask metrics).
//  - A photometric model: semantic metrics null, not an error.
//  - --refine / --mask-source refined with the tiny model packed with SAM2.1 (spar_goldens).
//  - Wrong input: exit code != 0, one line "spar: error: ...", no output file.
// Runs asked to validate have the Khronos validation layer with synchronization validation on
// (runValidated), which fails the test on any validation message.
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "tests/golden_support.h"
#include "tests/cli_test_support.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

const fs::path& scratch() { return scratchDir("spar_eval"); }

using RunResult = CommandResult;

RunResult run(const std::vector<std::string>& argv, bool validation = false) {
  return validation ? runValidated(argv, scratch()) : runCommand(argv, scratch());
}

RunResult sparEval(std::vector<std::string> args, bool validation = false) {
  args.insert(args.begin(), {SPAR_CLI, "eval"});
  return run(args, validation);
}

// The test scenes, made once per process by the scene generator (Debian's python).
fs::path makeScenes(const std::string& name, int count, int size) {
  const fs::path dir = scratch() / name;
  if (fs::exists(dir)) return dir;
  const RunResult r = run({SPAR_PYTHON, std::string(SPAR_SOURCE_DIR) + "/scenes/spar-scenes", "split", "--split",
                           "test", "--count", std::to_string(count), "--size", std::to_string(size), "--out",
                           dir.string()});
  EXPECT_EQ(r.code, 0) << r.err;
  return dir;
}

std::string semanticModel() { return semanticGoldenPath("tiny_semantic.spar"); }

void expectNoValidationMessages(const RunResult& r) {
  for (const std::string* s : {&r.out, &r.err}) {
    EXPECT_EQ(s->find("VUID"), std::string::npos) << *s;
    EXPECT_EQ(s->find("Validation"), std::string::npos) << *s;
  }
}

// `spar eval ARGS --out OUT`, checked (exit 0, no validation message, result.html beside with a
// row per K), its result.json parsed. A request this process has run already (a program's
// tests share one process) is not run again: its file is copied to OUT.
json evalOk(const std::vector<std::string>& args, const fs::path& out) {
  static std::map<std::vector<std::string>, fs::path> done;
  if (auto it = done.find(args); it != done.end() && fs::exists(it->second)) {
    fs::copy_file(it->second, out, fs::copy_options::overwrite_existing);
    std::ifstream in(out);
    return json::parse(in);
  }
  done[args] = out;
  std::vector<std::string> all = args;
  all.insert(all.end(), {"--out", out.string()});
  const RunResult r = sparEval(all, true);
  EXPECT_EQ(r.code, 0) << r.err;
  expectNoValidationMessages(r);
  std::printf("%s", r.out.c_str());
  std::ifstream in(out);
  EXPECT_TRUE(in.good()) << out;
  json doc = in.good() ? json::parse(in) : json();
  // Beside result.json its page (index_page.h): one table row per K of the results.
  fs::path page = out;
  page.replace_extension(".html");
  std::ifstream html(page);
  EXPECT_TRUE(html.good()) << page;
  const std::string text((std::istreambuf_iterator<char>(html)), std::istreambuf_iterator<char>());
  size_t rows = 0;
  for (size_t at = text.find("<tr><td>"); at != std::string::npos; at = text.find("<tr><td>", at + 1)) ++rows;
  if (doc.contains("results")) {
    EXPECT_EQ(rows, doc["results"].size()) << page;
  }
  return doc;
}

void expectInRange(const json& v, const std::string& what, double lo, double hi) {
  ASSERT_TRUE(v.is_number()) << what << " = " << v;
  const double x = v.get<double>();
  EXPECT_TRUE(std::isfinite(x)) << what;
  EXPECT_GE(x, lo) << what;
  EXPECT_LE(x, hi) << what;
}

// The fields of PROTOCOL.md for --views 2,3 on 2 scenes of 8 frames.
void expectLayout(const json& doc, const std::string& mode, bool semantic, bool masks) {
  EXPECT_EQ(doc.at("format"), "spar-eval");
  EXPECT_EQ(doc.at("version"), 1);
  EXPECT_TRUE(doc.at("model").is_string());
  EXPECT_EQ(doc.at("runner"), "engine");
  EXPECT_EQ(doc.at("precision"), "fp32");
  EXPECT_EQ(doc.at("mode"), mode);
  EXPECT_EQ(doc.at("scenes"), 2);
  EXPECT_EQ(doc.at("frames"), 8);
  const json& res = doc.at("results");
  ASSERT_EQ(res.size(), 2u);
  for (const auto& [k, targets] : {std::pair<std::string, int>{"2", 12}, {"3", 10}}) {
    const json& r = res.at(k);
    const std::string at = mode + " K=" + k + " ";
    for (const char* key : {"psnr", "ssim", "psnr_nearest_input", "ssim_nearest_input", "psnr_mean_colour",
                            "mask_miou", "mask_iou_dynamic", "mask_recall", "refined_mask_miou",
                            "refined_mask_iou_dynamic", "refined_mask_recall", "sem_miou", "sem_accuracy", "target_views",
                            "seconds", "ms_per_scene"})
      EXPECT_TRUE(r.contains(key)) << at << key;
    EXPECT_EQ(r.size(), 16u) << at;
    EXPECT_FALSE(doc.at("refine").get<bool>());
    for (const char* key : {"refined_mask_miou", "refined_mask_iou_dynamic", "refined_mask_recall"})
      EXPECT_TRUE(r.at(key).is_null()) << at << key;  // no SAM2.1 without --refine
    expectInRange(r.at("psnr"), at + "psnr", 0, 100);
    expectInRange(r.at("ssim"), at + "ssim", -1, 1);
    // the baselines (PROTOCOL.md): the nearest input copied, the inputs' mean colour
    expectInRange(r.at("psnr_nearest_input"), at + "psnr_nearest_input", 0, 100);
    expectInRange(r.at("ssim_nearest_input"), at + "ssim_nearest_input", -1, 1);
    expectInRange(r.at("psnr_mean_colour"), at + "psnr_mean_colour", 0, 100);
    for (const char* key : {"mask_miou", "mask_iou_dynamic", "mask_recall"}) {
      if (masks) expectInRange(r.at(key), at + key, 0, 1);
      else EXPECT_TRUE(r.at(key).is_null()) << at << key;
    }
    for (const char* key : {"sem_miou", "sem_accuracy"}) {
      if (semantic) expectInRange(r.at(key), at + key, 0, 1);
      else EXPECT_TRUE(r.at(key).is_null()) << at << key;
    }
    EXPECT_EQ(r.at("target_views"), targets) << at;
    expectInRange(r.at("seconds"), at + "seconds", 1e-6, 1e6);
    expectInRange(r.at("ms_per_scene"), at + "ms_per_scene", 1e-3, 1e9);
  }
}

TEST(spar_eval, ModesOnTheSemanticModel) {
  const fs::path scenes = makeScenes("scenes", 2, 128);
  const std::vector<std::string> base = {"--model", semanticModel(), "--scenes", scenes.string(), "--views", "2,3"};
  auto with = [&](std::vector<std::string> extra) {
    std::vector<std::string> a = base;
    a.insert(a.end(), extra.begin(), extra.end());
    return a;
  };
  const json def = evalOk(base, scratch() / "default.json");
  const json noGating = evalOk(with({"--no-gating"}), scratch() / "no_gating.json");
  const json still = evalOk(with({"--assume-static"}), scratch() / "assume_static.json");
  expectLayout(def, "default", true, true);
  expectLayout(noGating, "no-gating", true, true);
  expectLayout(still, "assume-static", true, false);
  for (const char* k : {"2", "3"}) {
    const json &d = def.at("results").at(k), &n = noGating.at("results").at(k), &s = still.at("results").at(k);
    // No gating renders as a static scene: the same tokens reach the scene encoder.
    for (const char* key : {"psnr", "ssim", "sem_miou", "sem_accuracy"})
      EXPECT_NEAR(n.at(key).get<double>(), s.at(key).get<double>(), 1e-9) << "K=" << k << " " << key;
    // Gating comes after CV-DRP: the masks do not depend on it.
    for (const char* key : {"mask_miou", "mask_iou_dynamic", "mask_recall"})
      EXPECT_EQ(d.at(key), n.at(key)) << "K=" << k << " " << key;
    // The baselines depend on the scenes and the views only.
    for (const char* key : {"psnr_nearest_input", "ssim_nearest_input", "psnr_mean_colour"}) {
      EXPECT_EQ(d.at(key), n.at(key)) << "K=" << k << " " << key;
      EXPECT_EQ(d.at(key), s.at(key)) << "K=" << k << " " << key;
    }
  }
}

// The engine's numbers and the PyTorch reference's (evaluation/spar-eval-reference, float32) on
// the same scenes and model agree within 0.005 (dB for PSNR): spar-eval-compare's verdict.
TEST(spar_eval, EngineAgreesWithReference) {
  const fs::path scenes = makeScenes("scenes", 2, 128);
  const std::string tools = std::string(SPAR_SOURCE_DIR) + "/evaluation/";
  for (const std::string mode : {"default", "assume-static"}) {
    std::vector<std::string> extra;
    if (mode != "default") extra.push_back("--" + mode);
    std::vector<std::string> engine = {"--model", semanticModel(), "--scenes", scenes.string(), "--views", "2,3"};
    engine.insert(engine.end(), extra.begin(), extra.end());
    evalOk(engine, scratch() / ("engine_" + mode + ".json"));
    std::vector<std::string> ref = {SPAR_PYTHON, tools + "spar-eval-reference", "--checkpoint",
                                    semanticGoldenPath("tiny_semantic.pt"), "--config",
                                    semanticGoldenPath("tiny_semantic.json"), "--bpe", clipBpePath(), "--scenes",
                                    scenes.string(), "--views", "2,3", "--quiet", "--out",
                                    (scratch() / ("reference_" + mode + ".json")).string()};
    ref.insert(ref.end(), extra.begin(), extra.end());
    const RunResult r = run(ref);
    ASSERT_EQ(r.code, 0) << r.err;
    const RunResult cmp = run({SPAR_PYTHON, tools + "spar-eval-compare", (scratch() / ("engine_" + mode + ".json")).string(),
                               (scratch() / ("reference_" + mode + ".json")).string(), "--tolerance", "0.005"});
    std::printf("%s", cmp.out.c_str());
    EXPECT_EQ(cmp.code, 0) << mode << ": " << cmp.out << cmp.err;
  }
}

// --refine: SAM2.1's masks of every frame scored beside CV-DRP's (the paper's two rows), the
// rendering and CV-DRP's own scores unchanged; --mask-source refined gates with them (other
// views rendered, the same masks scored). The model: the tiny one with mixed masks and a tiny
// SAM2.1 (fixture spar_goldens), so SAM2 refines views rather than skipping them.
TEST(spar_eval, RefineScoresSam2MasksBesideCvDrps) {
  const fs::path scenes = makeScenes("scenes", 2, 128);
  const std::vector<std::string> base = {"--model", goldenPath("tiny_sam2.spar"), "--scenes", scenes.string(),
                                         "--views", "3", "--max-scenes", "1"};
  auto with = [&](const std::string& a, const std::string& b = "") {
    std::vector<std::string> args = base;
    args.push_back(a);
    if (!b.empty()) args.push_back(b);
    return args;
  };
  const json plain = evalOk(base, scratch() / "refine_plain.json");
  const json refined = evalOk(with("--refine"), scratch() / "refine.json");
  const json gated = evalOk(with("--mask-source", "refined"), scratch() / "refine_gated.json");
  EXPECT_FALSE(plain.at("refine").get<bool>());
  EXPECT_TRUE(refined.at("refine").get<bool>());
  EXPECT_EQ(refined.at("mode"), "default");
  EXPECT_EQ(gated.at("mode"), "refined-gating");
  const json &p = plain.at("results").at("3"), &r = refined.at("results").at("3"), &g = gated.at("results").at("3");
  for (const char* key : {"refined_mask_miou", "refined_mask_iou_dynamic", "refined_mask_recall"}) {
    EXPECT_TRUE(p.at(key).is_null()) << key;
    expectInRange(r.at(key), key, 0, 1);
    EXPECT_EQ(r.at(key), g.at(key)) << key;  // the gating comes after the masks
  }
  for (const char* key : {"mask_miou", "mask_iou_dynamic", "mask_recall"}) {
    EXPECT_EQ(p.at(key), r.at(key)) << key;
    EXPECT_EQ(p.at(key), g.at(key)) << key;
  }
  // SAM2's masks are its own, not CV-DRP's thresholded (which a run skipping every view keeps)
  EXPECT_NE(r.at("refined_mask_miou"), r.at("mask_miou"));
  EXPECT_EQ(p.at("psnr"), r.at("psnr"));  // CV-DRP's probabilities still gate
  EXPECT_NE(p.at("psnr"), g.at("psnr"));  // the refined hard masks gate
  std::ifstream html(scratch() / "refine.html");
  const std::string page((std::istreambuf_iterator<char>(html)), std::istreambuf_iterator<char>());
  EXPECT_NE(page.find("<th>refined mask mIoU</th>"), std::string::npos);
}

TEST(spar_eval, PhotometricModelHasNoSemanticMetrics) {
  const fs::path scenes = makeScenes("scenes", 2, 128);
  const json doc = evalOk({"--model", tinyModelPath(), "--scenes", scenes.string(), "--views", "3,2"},
                          scratch() / "photometric.json");
  expectLayout(doc, "default", false, true);
}

TEST(spar_eval, WrongInputIsOneLineAndNoOutput) {
  const fs::path scenes = makeScenes("scenes", 2, 128);
  const fs::path small = makeScenes("scenes_64", 1, 64);  // not the model's size
  const fs::path empty = scratch() / "empty";
  fs::create_directories(empty);
  const std::string model = semanticModel(), dir = scenes.string();
  struct Bad {
    std::string name;
    std::vector<std::string> args;
    int code;
    std::string says;
  };
  const std::vector<Bad> cases = {
      {"missing_dir", {"--model", model, "--scenes", (scratch() / "nope").string()}, 1, "scenes directory not found"},
      {"no_scenes", {"--model", model, "--scenes", empty.string()}, 1, "no scene_* folders"},
      {"size_mismatch", {"--model", model, "--scenes", small.string()}, 1, "does not resize"},
      {"missing_model", {"--model", (scratch() / "nope.spar").string(), "--scenes", dir}, 1, "model not found"},
      {"views_one", {"--model", model, "--scenes", dir, "--views", "1"}, 2, "--views 1"},
      {"views_too_many", {"--model", model, "--scenes", dir, "--views", "2,9"}, 2, "--views 9"},
      {"views_all_frames", {"--model", model, "--scenes", dir, "--views", "8"}, 2, "--views 8"},
      {"views_not_numbers", {"--model", model, "--scenes", dir, "--views", "2,three"}, 2, "comma-separated"},
      {"gating_and_static", {"--model", model, "--scenes", dir, "--no-gating", "--assume-static"}, 2, "excludes"},
      {"max_scenes_zero", {"--model", model, "--scenes", dir, "--max-scenes", "0"}, 2, "--max-scenes"},
      {"bad_precision", {"--model", model, "--scenes", dir, "--precision", "int8"}, 2, "--precision"},
      {"refine_without_sam2", {"--model", model, "--scenes", dir, "--refine"}, 1, "no SAM2.1 weights"},
      {"refine_and_static", {"--model", model, "--scenes", dir, "--refine", "--assume-static"}, 2, "excludes"},
      {"bad_mask_source", {"--model", model, "--scenes", dir, "--mask-source", "soft"}, 2, "--mask-source"},
  };
  for (const Bad& c : cases) {
    const fs::path out = scratch() / ("out_" + c.name + ".json");
    std::vector<std::string> args = c.args;
    args.insert(args.end(), {"--out", out.string()});
    const RunResult r = sparEval(args);
    EXPECT_EQ(r.code, c.code) << c.name << ": " << r.err;
    const auto lines = r.errLines();
    ASSERT_EQ(lines.size(), 1u) << c.name << ": stderr was:\n" << r.err;
    EXPECT_EQ(lines[0].rfind("spar: error: ", 0), 0u) << lines[0];
    EXPECT_NE(lines[0].find(c.says), std::string::npos) << c.name << ": " << lines[0];
    EXPECT_FALSE(fs::exists(out)) << c.name;
    EXPECT_FALSE(fs::exists(out.string() + ".tmp")) << c.name;
    std::printf("  %-18s exit %d  %s\n", c.name.c_str(), r.code, lines[0].c_str());
  }
}

}  // namespace
}  // namespace spar::test
