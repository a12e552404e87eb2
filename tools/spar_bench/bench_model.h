// spar-bench --model: the whole SPAR pipeline on synthetic inputs (seeded random images, no
// image files: the GPU check carries binaries that link nothing but libvulkan), each stage's
// GPU time. A first run (weights uploaded, kernels created and built) is reported apart from
// the timed runs, whose per-stage median is the figure.
#pragma once
#include <nlohmann/json.hpp>

#include <cstdint>
#include <string>
#include <vector>

#include "spar/engine_options.h"

namespace spar::bench {

struct ModelBenchArgs {
  std::string model;           // packed .spar
  int64_t views = 4;           // input views
  int64_t targets = 4;         // target views rendered with their estimated cameras
  int64_t height = 0, width = 0;  // 0: the model's own size
  std::string precision = "fp32";  // fp32 | fp16 | q8 | q4 weight matrices (spar/precision.h)
  bool assumeStatic = false;   // no DINOv3 / CV-DRP
  bool semantic = false;       // render semantic features too (models with the semantic branch)
  int repeats = 3;
};

// The synthetic frames [views, 3, height, width] in [0, 1): value i is the top 24 bits of
// murmur3's finalizer of (i + 0x9E3779B9 * 12345 mod 2^32), over 2^24.
// scripts/gpu/gpu_reference_bench.py makes the same frames for the PyTorch reference.
std::vector<float> syntheticImages(int64_t views, int64_t height, int64_t width);

// Runs it; the document holds the request, the first run's wall and build time, and per stage
// the median GPU and wall ms of the timed runs, with their sum. Throws spar::Error.
// The whole run goes through the public library (include/spar/) on a context made from `options`.
nlohmann::ordered_json benchModel(const EngineOptions& options, const ModelBenchArgs& args);

// The document as a table on stdout.
void printModelBench(const nlohmann::ordered_json& doc);

}  // namespace spar::bench
