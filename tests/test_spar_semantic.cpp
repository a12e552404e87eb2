// The pipeline of a model with the semantic branch (the tiny preset: LSeg features, semantic
// tokens gated like the image tokens, scene encoder over scene + image + semantic tokens, decoder
// with semantic ray queries, semantic head) against the float64 reference, stage by stage
// (tests/pipeline_check.cpp; fixture spar_goldens_semantic).
#include "pipeline_check.h"
#include "test_support.h"

namespace spar::test {
namespace {

class SparSemanticTest : public EngineTest {};

// The reference's LSeg features fed in: everything from the semantic tokens on.
TEST_F(SparSemanticTest, SemanticStagesMatchReferenceGivenLsegFeatures) {
  runGoldenCase(eng(), semanticGoldenPath("semantic"),
                {.model = semanticGoldenPath("tiny_semantic.spar"), .semantic = true, .goldenLseg = true});
}

// Everything on the engine, LSeg included (the input views only).
TEST_F(SparSemanticTest, WholeSemanticPipelineMatchesReference) {
  runGoldenCase(eng(), semanticGoldenPath("semantic"),
                {.model = semanticGoldenPath("tiny_semantic.spar"), .semantic = true});
}

// Rendering mode (a camera path) with semantic features of the path's views.
TEST_F(SparSemanticTest, PathWithSemanticFeaturesMatchesReference) {
  runGoldenCase(eng(), semanticGoldenPath("semantic_path"),
                {.model = semanticGoldenPath("tiny_semantic.spar"), .pathCameras = true, .semantic = true,
                 .goldenLseg = true});
}

}  // namespace
}  // namespace spar::test
