// Runs the photometric pipeline on one golden case (tests/golden_support.h) and compares every
// stage the pipeline keeps with the reference's float64 golden of the same name, each with its
// own NMSE threshold (model/stage_tolerances.h). Shared by test_spar_pipeline (the plain cases) and test_spar_stiff.
#pragma once
#include <map>
#include <string>
#include <vector>

#include "engine/engine.h"
#include "golden_support.h"
#include "model/spar_pipeline.h"
#include "model/stage_tolerances.h"

namespace spar::test {

struct CaseOptions {
  std::string model;           // packed model path ("" = the tiny model)
  bool assumeStatic = false;
  bool targetMotion = true;    // also CV-DRP over the targets (compared when the case has them)
  bool pathCameras = false;    // render the golden's render_c2w instead of the targets
  double scale = 1.0;          // multiplies every threshold (stiff cases document theirs)
  // Semantic models: compare the semantic stages too and render the semantic features; with
  // goldenLseg the reference's LSeg features are fed in (the semantic tokens onwards are then
  // compared without LSeg's own error).
  bool semantic = false;
  bool goldenLseg = false;
  DType weightType = DType::F32;  // SparPipelineOptions::weightType
  // Stage -> NMSE threshold replacing the fp32 one (test_spar_precision's fp16 table).
  std::map<std::string, double> thresholds;
  // Mask pixels may differ where the reference's probability is this close to the threshold.
  double maskTieBand = kMaskTieBand;
};

// Runs the case and checks all stages; returns the pipeline's stage times for further checks.
std::vector<StageTime> runGoldenCase(Engine& engine, const std::string& caseName, const CaseOptions& options);

// Per-stage NMSE thresholds of the pipeline with fp16 weights (measured; see pipeline_check.cpp).
const std::map<std::string, double>& fp16WeightThresholds();

// The input images of a case, prepared by the engine (imaging/image_prep.h).
std::vector<float> prepareFrames(const GoldenCase& g, int64_t h, int64_t w);

}  // namespace spar::test
