// spar-modes (tools/spar_modes/main.cpp) as a user runs it, on its default inputs: the tiny model
// of the spar_goldens fixture. Checks the report's structure, not its timings: every mode
// present, every number finite, the static modes without DINOv3 / CV-DRP and with fewer weight
// bytes, fp16 weights with fewer bytes than fp32 and q8 / q4 fewer still, errors of the expected size, the markdown on
// stdout and the SVG plot written.
#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <string>

#include "tests/golden_support.h"
#include "tests/test_support.h"

#ifndef SPAR_MODES
#error "SPAR_MODES (path of the built spar-modes) is defined by tools/CMakeLists.txt"
#endif

namespace spar::test {
namespace {

namespace fs = std::filesystem;

const fs::path& scratch() { return scratchDir("spar_modes"); }


struct Result {
  int code = -1;
  std::string out, err;
};

Result run(const std::string& args) {
  const fs::path out = scratch() / "stdout.txt", err = scratch() / "stderr.txt";
  const std::string cmd = std::string("'") + SPAR_MODES + "' " + args + " >'" + out.string() + "' 2>'" + err.string() + "'";
  const int status = std::system(cmd.c_str());
  return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, readText(out), readText(err)};
}

bool finiteNumber(const nlohmann::json& j) { return j.is_number() && std::isfinite(j.get<double>()); }

TEST(SparModes, ReportOnTinyModel) {
  const Result r = run("--repeat 1 --out '" + (scratch() / "report").string() + "'");
  ASSERT_EQ(r.code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(readText(scratch() / "report" / "modes.json"));
  const std::vector<std::string> names = {"fp32",        "fp16",        "q8",        "q4",
                                          "fp32-static", "fp16-static", "q8-static", "q4-static"};
  ASSERT_EQ(j.at("modes").size(), names.size());
  std::map<std::string, nlohmann::json> modes;
  for (const auto& m : j.at("modes")) modes[m.at("mode").get<std::string>()] = m;
  for (const std::string& name : names) {
    SCOPED_TRACE(name);
    ASSERT_TRUE(modes.count(name));
    const nlohmann::json& m = modes.at(name);
    for (const char* key : {"wall_ms", "gpu_ms", "first_run_ms"}) {
      EXPECT_TRUE(finiteNumber(m.at(key))) << key;
      EXPECT_GT(m.at(key).get<double>(), 0.0) << key;
    }
    EXPECT_GT(m.at("weight_bytes").get<uint64_t>(), 0u);
    EXPECT_GE(m.at("device_peak_bytes").get<uint64_t>(), m.at("weight_bytes").get<uint64_t>());
    std::set<std::string> stages;
    for (const auto& s : m.at("stages")) {
      stages.insert(s.at("name").get<std::string>());
      EXPECT_TRUE(finiteNumber(s.at("gpu_ms")) && finiteNumber(s.at("wall_ms"))) << s.dump();
    }
    for (const char* s : {"image_tokens", "pose_estimator", "rays", "gating", "scene_encoder", "renderer"})
      EXPECT_TRUE(stages.count(s)) << s;
    const bool isStatic = m.at("assume_static").get<bool>();
    EXPECT_EQ(isStatic, stages.count("dino_v3") == 0);
    EXPECT_EQ(isStatic, stages.count("cv_drp") == 0);
    const nlohmann::json& e = m.at("vs_reference");
    EXPECT_TRUE(finiteNumber(e.at("rgb_psnr_db")) && finiteNumber(e.at("rgb_max_abs"))) << e.dump();
    EXPECT_TRUE(finiteNumber(m.at("vs_same_mode_reference").at("rgb_psnr_db")));
    if (isStatic) {
      EXPECT_TRUE(e.at("mask_agreement").is_null());
    } else {
      ASSERT_TRUE(finiteNumber(e.at("mask_agreement")));
      EXPECT_GE(e.at("mask_agreement").get<double>(), 0.999);  // measured: 100%
    }
    // The engine against the reference of its own mode (fp32 for q8 / q4): fp32 measured
    // 147 dB, fp16 99 dB, q8 72 dB, q4 48 dB.
    const std::string weights = m.at("weights");
    const double bound = weights == "f32" ? 120.0 : weights == "f16" ? 80.0 : weights == "q8" ? 60.0 : 40.0;
    EXPECT_GE(m.at("vs_same_mode_reference").at("rgb_psnr_db").get<double>(), bound) << weights;
  }
  const auto bytes = [&](const char* name) { return modes.at(name).at("weight_bytes").get<uint64_t>(); };
  EXPECT_LT(bytes("fp32-static"), bytes("fp32"));
  EXPECT_LT(bytes("fp16-static"), bytes("fp16"));
  EXPECT_LT(bytes("fp16"), bytes("fp32"));
  EXPECT_LT(bytes("fp16-static"), bytes("fp32-static"));
  EXPECT_LT(bytes("q8"), bytes("fp16"));
  EXPECT_LT(bytes("q4"), bytes("q8"));
  EXPECT_LT(bytes("q4-static"), bytes("q8-static"));

  // The table on stdout (and in modes.md), one row per mode; the plot with one point per mode.
  EXPECT_EQ(r.out, readText(scratch() / "report" / "modes.md"));
  for (const std::string& name : names) EXPECT_NE(r.out.find("| " + name + " |"), std::string::npos) << name;
  const std::string svg = readText(scratch() / "report" / "modes.svg");
  EXPECT_EQ(svg.rfind("<svg", 0), 0u);
  size_t circles = 0;
  for (size_t at = svg.find("<circle"); at != std::string::npos; at = svg.find("<circle", at + 1)) ++circles;
  EXPECT_EQ(circles, names.size());

  // A second report reuses the reference's goldens (same inputs) and may select modes.
  const Result again = run("--repeat 1 --modes fp16-static --out '" + (scratch() / "report").string() + "'");
  ASSERT_EQ(again.code, 0) << again.err;
  EXPECT_EQ(again.err.find("PyTorch reference: running"), std::string::npos) << again.err;
  EXPECT_EQ(nlohmann::json::parse(readText(scratch() / "report" / "modes.json")).at("modes").size(), 1u);
}

// The refine modes on the tiny model packed with SAM2.1 (fixture spar_goldens): SAM2's stage
// timed, its refined masks against the reference's refinement, and with the refined masks
// gating, the rendering against the reference's --mask-source refined run.
TEST(SparModes, RefineModesOnTheTinyModelWithSam2) {
  std::string frames;
  for (int i = 0; i < 5; ++i) frames += " '" + goldenPath("frame_" + std::to_string(i) + ".png") + "'";
  const fs::path out = scratch() / "refine";
  const Result r = run("--model '" + goldenPath("tiny_sam2.spar") + "' --checkpoint '" + goldenPath("masked/masked.pt") +
                       "' --config '" + goldenPath("tiny_photometric.json") + "' --frames" + frames +
                       " --inputs 0,2,4 --sam2 '" + goldenPath("tiny_sam2_weights.pt") + "' --sam2-config '" +
                       goldenPath("tiny_sam2_config.json") + "' --modes fp32,fp32-refine,fp32-refined --repeat 1 --out '" +
                       out.string() + "'");
  ASSERT_EQ(r.code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(readText(out / "modes.json"));
  std::map<std::string, nlohmann::json> modes;
  for (const auto& m : j.at("modes")) modes[m.at("mode").get<std::string>()] = m;
  ASSERT_EQ(modes.size(), 3u);
  const auto stageNames = [&](const char* mode) {
    std::set<std::string> names;
    for (const auto& st : modes.at(mode).at("stages")) names.insert(st.at("name").get<std::string>());
    return names;
  };
  EXPECT_EQ(stageNames("fp32").count("sam2_refine"), 0u);
  EXPECT_TRUE(modes.at("fp32").at("vs_reference").at("refined_mask_agreement").is_null());
  for (const char* name : {"fp32-refine", "fp32-refined"}) {
    SCOPED_TRACE(name);
    const nlohmann::json& m = modes.at(name);
    EXPECT_EQ(stageNames(name).count("sam2_refine"), 1u);
    EXPECT_GT(m.at("weight_bytes").get<uint64_t>(), modes.at("fp32").at("weight_bytes").get<uint64_t>());
    ASSERT_TRUE(finiteNumber(m.at("vs_reference").at("refined_mask_agreement")));
    EXPECT_GE(m.at("vs_reference").at("refined_mask_agreement").get<double>(), 0.999);  // measured: 100%
    EXPECT_GE(m.at("vs_same_mode_reference").at("rgb_psnr_db").get<double>(), 120.0);   // measured: 147 dB
  }
  // CV-DRP's masks still gate with -refine: the rendering is fp32's; the refined masks gating
  // render other views (the whole model's reference is then off by what the masks change).
  EXPECT_EQ(modes.at("fp32-refine").at("vs_reference").at("rgb_psnr_db"),
            modes.at("fp32").at("vs_reference").at("rgb_psnr_db"));
  EXPECT_LT(modes.at("fp32-refined").at("vs_reference").at("rgb_psnr_db").get<double>(), 120.0);
  EXPECT_NE(r.out.find("| fp32-refined |"), std::string::npos);
}

// --labels on the semantic model (fixture spar_goldens_semantic): the targets' label maps in
// every mode against the reference's; with q8 weights (LSeg's convolutions and ViT, CLIP's
// tower quantized) the label maps of this tiny model stay the reference's (measured: 100 %).
TEST(SparModes, LabelMapsOnTheSemanticModel) {
  std::string frames;
  for (int i = 0; i < 5; ++i) frames += " '" + semanticGoldenPath("frame_" + std::to_string(i) + ".png") + "'";
  const fs::path out = scratch() / "labels";
  const Result r = run("--model '" + semanticGoldenPath("tiny_semantic.spar") + "' --checkpoint '" +
                       semanticGoldenPath("tiny_semantic.pt") + "' --config '" + semanticGoldenPath("tiny_semantic.json") +
                       "' --frames" + frames + " --inputs 0,2,4 --labels sofa,window,floor --modes q8 --repeat 1 --out '" +
                       out.string() + "'");
  ASSERT_EQ(r.code, 0) << r.err;
  const nlohmann::json j = nlohmann::json::parse(readText(out / "modes.json"));
  EXPECT_EQ(j.at("labels"), nlohmann::json({"sofa", "window", "floor"}));
  ASSERT_EQ(j.at("modes").size(), 1u);
  for (const auto& m : j.at("modes")) {
    SCOPED_TRACE(m.at("mode").get<std::string>());
    const nlohmann::json& agreement = m.at("vs_reference").at("label_map_agreement");
    ASSERT_TRUE(finiteNumber(agreement));
    EXPECT_GE(agreement.get<double>(), 0.99);
  }
  EXPECT_NE(r.out.find("label agreement %"), std::string::npos) << r.out;
}

TEST(SparModes, BadCommandLine) {
  // the fixture's model has no SAM2.1: its refine modes are refused (and not among the defaults)
  // (and prompts for a model without the semantic branch)
  for (const char* args : {"--modes fp8", "--repeat 0", "--frames a.png", "--modes fp32-refine", "--labels sofa"}) {
    SCOPED_TRACE(args);
    const Result r = run(args);
    EXPECT_EQ(r.code, 2);
    EXPECT_EQ(r.err.rfind("spar-modes: error: ", 0), 0u) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  }
}

}  // namespace
}  // namespace spar::test
