// The whole photometric pipeline of the tiny model with fp16 weights on cooperative matrices
// (shaders/gemm_coopmat.comp), against the reference's float64 goldens (fixture spar_goldens).
// Runs where test_coopmat does (CTest: lavapipe 26.1 through scripts/portability/coopmat-lavapipe.sh, with
// SPAR_KERNELS=coopmat); fails on a device without cooperative matrices.
#include "engine/kernel_plan.h"
#include "tests/pipeline_check.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

class CoopMatModelTest : public EngineTest {};

// The whole photometric pipeline of the tiny model with fp16 weights on cooperative matrices,
// stage by stage against the reference's float64 goldens: the activations entering every
// product and attention (attention_coopmat.comp: q, k, v and the probabilities) are rounded to
// fp16 here too, yet every stage stays within the fp16-weight thresholds of test_spar_precision
// (10x what fp16 weights alone measured; measured here on lavapipe 26.1: at most 0.43 of a
// threshold, render_plucker 8.5e-11; the token stages 0.19, e.g. img_tokens 7.4e-8), and no
// motion-mask pixel differs.
TEST_F(CoopMatModelTest, TinyModelWithFp16WeightsMatchesGoldens) {
  ASSERT_EQ(eng().plan().gemmF16, KernelFamily::CoopMat) << eng().caps().name << ": no cooperative matrices";
  CaseOptions o;
  o.weightType = DType::F16;
  o.thresholds = fp16WeightThresholds();
  runGoldenCase(eng(), "interleaved", o);
}

}  // namespace
}  // namespace spar::test
