// The tiny photometric model with fp16 weights on the GPU family's fp16-arithmetic GEMM
// (gemm_tiled.comp, FP16_MATH: what a GPU with shaderFloat16 and no cooperative matrices runs
// for fp16 weights), forced on this device (KernelTuning::kernels = "gpu-fp16"), stage by stage
// against the reference's float64 goldens (fixture spar_goldens). The activations entering
// every product are rounded to fp16 and each run of 4 products is summed in fp16, so the
// thresholds are the fp16-weight ones (pipeline_check.cpp) times kScale, measured below.
#include "engine/kernel_plan.h"
#include "tests/pipeline_check.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

// Largest ratio of a stage's NMSE to its fp16-weight threshold, measured on lavapipe (Mesa 22.3)
// over the four cases below: 1.32 (render_plucker; c2w 0.96, plucker 0.90, the tokens 0.5-0.6):
// the cameras, which fp16 weights alone barely move, feel the fp16 activations most. The scale
// leaves 3x room.
constexpr double kScale = 4;

class SparFp16MathTest : public EngineTest {
 protected:
  static CaseOptions fp16Math(CaseOptions o) {
    o.weightType = DType::F16;
    o.thresholds = fp16WeightThresholds();
    o.scale = kScale;
    return o;
  }
  ScopedKernels family_{eng(), "gpu-fp16"};
};

TEST_F(SparFp16MathTest, Interleaved) {
  ASSERT_TRUE(eng().plan().fp16Math);
  runGoldenCase(eng(), "interleaved", fp16Math({}));
}
TEST_F(SparFp16MathTest, OddTargets) { runGoldenCase(eng(), "odd_targets", fp16Math({})); }
TEST_F(SparFp16MathTest, AssumeStatic) { runGoldenCase(eng(), "static", fp16Math({.assumeStatic = true})); }
TEST_F(SparFp16MathTest, PathCameras) { runGoldenCase(eng(), "path", fp16Math({.pathCameras = true})); }

}  // namespace
}  // namespace spar::test
