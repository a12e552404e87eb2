// spar-bench --model (samples/bench_model.h): the whole pipeline on synthetic inputs, through
// the built spar-bench (SPAR_BENCH) on the tiny photometric fixture, validation and
// synchronization validation on (runValidated):
//  - every stage that runs is reported with its GPU time, and the timed total is their sum;
//  - --assume-static leaves out DINOv3 and CV-DRP (no stage, fewer weights loaded);
//  - the program needs no image library (what the GPU check carries links only libvulkan of
//    the system's graphics stack: no OpenImageIO, libpng or ICU in its NEEDED entries).
// The suite is named "spar_bench_model" (`ctest -R spar_bench_model`).
#include <gtest/gtest.h>

#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "tests/golden_support.h"
#include "tests/test_support.h"

#ifndef SPAR_BENCH
#error "SPAR_BENCH (path of the built spar-bench) is defined by samples/CMakeLists.txt"
#endif

namespace spar::test {
namespace {

using json = nlohmann::json;

const std::filesystem::path& scratch() { return scratchDir("spar_bench_model"); }

json bench(const std::vector<std::string>& extra) {
  std::vector<std::string> argv = {SPAR_BENCH, "--model", goldenPath("tiny.spar"), "--views", "3", "--targets", "2",
                                   "--repeat", "2", "--json"};
  argv.insert(argv.end(), extra.begin(), extra.end());
  const CommandResult r = runValidated(argv, scratch());
  EXPECT_EQ(r.code, 0) << r.err;
  return r.code == 0 ? json::parse(r.out) : json();
}

std::set<std::string> stageNames(const json& doc) {
  std::set<std::string> names;
  for (const auto& s : doc["stages"]) names.insert(s["name"].get<std::string>());
  return names;
}

TEST(spar_bench_model, EveryStageTimedAndSummed) {
  const json doc = bench({});
  ASSERT_TRUE(doc.is_object());
  EXPECT_EQ(doc["request"]["inputs"], 3);
  EXPECT_EQ(doc["request"]["targets"], 2);
  for (const char* stage : {"image_tokens", "pose_estimator", "rays", "dino_v3", "cv_drp", "gating", "scene_encoder",
                            "render_rays", "renderer"})
    EXPECT_TRUE(stageNames(doc).count(stage)) << stage << " in " << doc["stages"].dump();
  double sum = 0;
  for (const auto& s : doc["stages"]) {
    EXPECT_GT(s["gpu_ms"].get<double>(), 0.0) << s.dump();
    EXPECT_GE(s["wall_ms"].get<double>(), s["gpu_ms"].get<double>() * 0.5) << s.dump();
    sum += s["gpu_ms"].get<double>();
  }
  // medians per stage against the median of the per-run sums: the same up to run-to-run spread
  EXPECT_NEAR(doc["total"]["gpu_ms"].get<double>(), sum, 0.5 * sum);
  EXPECT_GT(doc["first_run"]["wall_ms"].get<double>(), 0.0);
  EXPECT_GT(doc["weights_bytes_loaded"].get<double>(), 0.0);
}

TEST(spar_bench_model, AssumeStaticLeavesOutDinoAndCvDrp) {
  const json full = bench({}), still = bench({"--assume-static"});
  ASSERT_TRUE(still.is_object());
  EXPECT_FALSE(stageNames(still).count("dino_v3"));
  EXPECT_FALSE(stageNames(still).count("cv_drp"));
  EXPECT_TRUE(stageNames(still).count("renderer"));
  EXPECT_LT(still["weights_bytes_loaded"].get<double>(), full["weights_bytes_loaded"].get<double>());
}

TEST(spar_bench_model, BadRequestIsOneLine) {
  const CommandResult r = runValidated({SPAR_BENCH, "--model", goldenPath("tiny.spar"), "--size", "100x128"}, scratch());
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_NE(r.err.find("spar-bench: image size 100x128 (HxW) is not a multiple"), std::string::npos) << r.err;
}

TEST(spar_bench_model, NeedsNoImageLibrary) {
  const CommandResult r = runCommand({"readelf", "-d", SPAR_BENCH}, scratch());
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("libvulkan"), std::string::npos) << r.out;
  for (const char* lib : {"OpenImageIO", "libpng", "libicu", "libjpeg"})
    EXPECT_EQ(r.out.find(lib), std::string::npos) << lib << " in\n" << r.out;
}

}  // namespace
}  // namespace spar::test
