// The whole photometric pipeline (model/spar_pipeline.*) on the tiny model against the PyTorch
// reference's float64 goldens (tests/python/make_spar_goldens.py), stage by stage (thresholds
// and the comparison in tests/pipeline_check.cpp).
#include "pipeline_check.h"
#include "test_support.h"

namespace spar::test {
namespace {

class SparPipelineTest : public EngineTest {};

// Inputs 0, 2, 4 and targets 1, 3 of five frames with --assume-static: no DINOv3, no CV-DRP, no
// gating (the reference's assume_static).
TEST_F(SparPipelineTest, AssumeStaticMatchesReference) {
  const auto times = runGoldenCase(eng(), "static", {.assumeStatic = true});
  EXPECT_FALSE(times.empty());
}

// Inputs 0, 2, 4 and targets 1, 3: the canonical view (2) is an input; CV-DRP over the inputs
// (pairs (0,1), (1,2)) and the targets (pair (0,1)).
TEST_F(SparPipelineTest, InterleavedMatchesReference) { runGoldenCase(eng(), "interleaved", {}); }

// Inputs 1, 3 and targets 0, 2, 4: the canonical view is a target, and an odd target count pairs
// the middle target with its predecessor as well.
TEST_F(SparPipelineTest, OddTargetsMatchReference) { runGoldenCase(eng(), "odd_targets", {}); }

// Rendering mode: inputs only, three cameras along the path through the estimated input cameras
// (the reference's; the engine's own path is tested with the cameras).
TEST_F(SparPipelineTest, PathCamerasMatchReference) { runGoldenCase(eng(), "path", {.pathCameras = true}); }

}  // namespace
}  // namespace spar::test
