// spar-bench --model (tools/spar_bench/bench_model.h): the whole pipeline on synthetic inputs, through
// the built spar-bench (SPAR_BENCH) on the tiny photometric fixture, validation and
// synchronization validation on (runValidated):
//  - every stage that runs is reported with its GPU time, and the timed total is their sum;
//  - --assume-static leaves out DINOv3 and CV-DRP (no stage, fewer weights loaded);
//  - the program needs no image library (what the GPU check carries links only libvulkan of
//    the system's graphics stack: no OpenImageIO, libpng or ICU in its NEEDED entries);
//  - --peer times the op cases' CPU peer in the same run (tools/spar_bench/bench_peer.h).
// The suite is named "spar_bench_model" (`ctest -R spar_bench_model`).
#include <gtest/gtest.h>

#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "tools/spar_bench/bench_model.h"
#include "tests/golden_support.h"
#include "tests/test_support.h"

#ifndef SPAR_BENCH
#error "SPAR_BENCH (path of the built spar-bench) is defined by tools/CMakeLists.txt"
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
  EXPECT_GT(doc["total"]["wall_ms_unprofiled"].get<double>(), 0.0);
}

// What a run takes in commands, per stage: every stage dispatches, barriers order its
// dispatches, and the stages made of transformer blocks count them (the tiny model: 2
// pose-encoder, 2 scene-encoder and 2 decoder blocks, DINOv3's 2, and the renderer's blocks once
// per batch of views). A request without refinement waits on the host twice: once for the
// encode's one submission, once for the render call's.
TEST(spar_bench_model, EveryStageCountsItsCommands) {
  const json doc = bench({});
  ASSERT_TRUE(doc.is_object());
  std::map<std::string, json> stage;
  int64_t submits = 0;
  for (const auto& s : doc["stages"]) {
    stage[s["name"].get<std::string>()] = s;
    submits += s["submits"].get<int64_t>();
  }
  for (const auto& [name, s] : stage) {
    EXPECT_GE(s["dispatches"].get<int64_t>(), 1) << s.dump();
    EXPECT_LE(s["barriers"].get<int64_t>(), s["dispatches"].get<int64_t>()) << s.dump();
  }
  EXPECT_EQ(submits, 2) << doc["stages"].dump();
  EXPECT_LE(submits, 3);  // the GPU-speed issue's bar
  // A transformer block is at most 7 dispatches in every stage made of them (the GPU-speed
  // bar): SPAR's blocks with their q / k norm, DINOv3's with RoPE and layer scales.
  for (const char* name : {"pose_estimator", "dino_v3", "cv_drp", "scene_encoder", "renderer"}) {
    const int64_t blocks = stage[name]["transformer_blocks"].get<int64_t>();
    EXPECT_GE(blocks, 1) << name;
    EXPECT_GT(stage[name]["dispatches"].get<int64_t>(), blocks) << name;
    EXPECT_GE(stage[name]["block_dispatches"].get<int64_t>(), 5) << name;
    EXPECT_LE(stage[name]["block_dispatches"].get<int64_t>(), 7) << name;
  }
  EXPECT_EQ(stage["image_tokens"]["transformer_blocks"].get<int64_t>(), 0);
  EXPECT_EQ(stage["image_tokens"]["block_dispatches"].get<int64_t>(), 0);
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

// --peer: every case gets the CPU peer's time and the engine's speed as a multiple of it, and
// the peer runs with OpenBLAS's own choice of kernels even where the caller's environment holds
// it to Haswell's (OPENBLAS_CORETYPE, as this project's machines set it).
TEST(spar_bench_model, PeerTimesTheSameOpsInTheSameRun) {
  const CommandResult r = runValidated({SPAR_BENCH, "--only", "layernorm", "--repeat", "1", "--peer", "--json"},
                                       scratch(), "OPENBLAS_CORETYPE=Haswell OPENBLAS_L2_SIZE=512");
  ASSERT_EQ(r.code, 0) << r.err;
  const json doc = json::parse(r.out);
  const std::string peer = doc["peer"].get<std::string>();
  EXPECT_NE(peer.find("numpy"), std::string::npos) << peer;
  EXPECT_NE(peer.find("PyTorch"), std::string::npos) << peer;  // the row ops' peer
  const size_t kernels = peer.find("OpenBLAS, ");
  ASSERT_NE(kernels, std::string::npos) << peer;
  const CommandResult cpu = runCommand({"grep", "-c", "avx512f", "/proc/cpuinfo"}, scratch());
  if (cpu.code == 0) EXPECT_EQ(peer.find("Haswell kernels"), std::string::npos) << peer;
  ASSERT_EQ(doc["ops"].size(), 2u) << doc.dump();
  for (const auto& op : doc["ops"]) {
    ASSERT_TRUE(op["peer_ms"].is_number()) << op.dump();
    EXPECT_GT(op["peer_ms"].get<double>(), 0.0) << op.dump();
    EXPECT_NEAR(op["vs_peer"].get<double>(), op["peer_ms"].get<double>() / op["ms"].get<double>(), 1e-9) << op.dump();
  }
  const CommandResult model =
      runValidated({SPAR_BENCH, "--model", goldenPath("tiny.spar"), "--peer"}, scratch());
  EXPECT_EQ(model.code, 2);
  EXPECT_NE(model.err.find("--peer times the op cases"), std::string::npos) << model.err;
}

// --list-kernels: what each op runs and why, from the device's properties (CPU family here)
// or forced (SPAR_KERNELS=gpu: the GPU family on this CPU device).
TEST(spar_bench_model, ListKernelsSaysWhatAndWhy) {
  CommandResult r = runValidated({SPAR_BENCH, "--list-kernels"}, scratch(), "SPAR_PIPELINE_CACHE=0");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("linear, fp32 weights: gemm.comp"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("why: CPU device"), std::string::npos) << r.out;
  r = runValidated({SPAR_BENCH, "--list-kernels", "--json"}, scratch(), "SPAR_PIPELINE_CACHE=0 SPAR_KERNELS=gpu");
  ASSERT_EQ(r.code, 0) << r.err;
  const json doc = json::parse(r.out);
  std::string all;
  for (const auto& line : doc["kernels"]) all += line.get<std::string>() + "\n";
  EXPECT_NE(all.find("linear, fp32 weights: gemm_tiled.comp"), std::string::npos) << all;
  EXPECT_NE(all.find("attention: attention_flash.comp"), std::string::npos) << all;
  EXPECT_NE(all.find("SPAR_KERNELS=gpu"), std::string::npos) << all;
  r = runValidated({SPAR_BENCH, "--list-kernels"}, scratch(), "SPAR_PIPELINE_CACHE=0 SPAR_KERNELS=coopmat");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("SPAR_KERNELS=coopmat"), std::string::npos) << r.err;
}

// The synthetic frames are the ones scripts/gpu/gpu_reference_bench.py makes for the PyTorch
// reference (the same hash in Python): the GPU check compares both on the same inputs.
TEST(spar_bench_model, SyntheticFramesAreThePythonScripts) {
  const std::vector<float> frames = bench::syntheticImages(2, 16, 24);
  const std::string code = "from gpu_reference_bench import synthetic_images; "
                           "x = synthetic_images(2, 16, 24).ravel(); print(len(x)); print(' '.join(repr(float(v)) for v in x))";
  const CommandResult r = runCommand({SPAR_PYTHON, "-c", code}, scratch(), std::string("PYTHONPATH=") + SPAR_PYTHONPATH);
  ASSERT_EQ(r.code, 0) << r.err;
  std::istringstream in(r.out);
  size_t n = 0;
  in >> n;
  ASSERT_EQ(n, frames.size());
  double lo = 1, hi = 0;
  for (size_t i = 0; i < n; ++i) {
    double v = 0;
    in >> v;
    ASSERT_EQ(float(v), frames[i]) << "value " << i;
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  }
  EXPECT_LT(lo, 0.01);  // spread over [0, 1)
  EXPECT_GT(hi, 0.99);
}

}  // namespace
}  // namespace spar::test
