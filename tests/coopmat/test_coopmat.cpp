// The cooperative-matrix GEMM (shaders/gemm_coopmat.comp, VK_KHR_cooperative_matrix) and
// attention (shaders/attention_coopmat.comp) against float64, on a device that has the extension: CTest runs this program on lavapipe 26.1
// (scripts/portability/coopmat-lavapipe.sh) with SPAR_KERNELS=coopmat, and scripts/gpu/gpu-check.sh on a GPU.
// It fails, not skips, on a device without cooperative matrices. No image I/O: it runs where
// only the Vulkan loader is (scripts/gpu/gpu-check.sh); the whole model on cooperative matrices is
// test_coopmat_model.cpp.
//
// What the kernel computes: x and w rounded to fp16 (values beyond +-65504 saturate), products
// accumulated in fp32. So against float64 on the rounded inputs the error is fp32 accumulation
// only (thresholds of the fp32 GEMM tests); against the unrounded inputs it is fp16 rounding.
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "engine/kernel_plan.h"
#include "engine/kernel_tuner.h"
#include "engine/ops/attention.h"
#include "engine/ops/linear.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

class CoopMatTest : public EngineTest {};

TEST_F(CoopMatTest, DeviceHasCooperativeMatrices) {
  const DeviceCaps& caps = eng().caps();
  ASSERT_TRUE(caps.cooperativeMatrix) << caps.name << " has no VK_KHR_cooperative_matrix (run under scripts/portability/coopmat-lavapipe.sh)";
  const KernelPlan& plan = eng().plan();
  EXPECT_EQ(plan.gemmF16, KernelFamily::CoopMat);
  for (const auto& line : describePlan(plan, caps)) std::printf("    %s\n", line.c_str());
}

struct Case {
  int64_t M, N, K;
  bool bias;
  Activation act;
  DType xType, yType;
};

class CoopMatShapes : public EngineTest, public ::testing::WithParamInterface<Case> {};

// Odd sizes hit every edge: rows and columns past the workgroup tile, K not a multiple of the
// multiply-add's K (and not of 4: R texels), one element.
TEST_P(CoopMatShapes, MatchesFloat64OnFp16Inputs) {
  const Case c = GetParam();
  auto x = randomUniform(c.M * c.K, -1, 1, 31), w = randomUniform(c.N * c.K, -1, 1, 32);
  auto b = c.bias ? randomUniform(c.N, -1, 1, 33) : std::vector<float>{};
  Tensor tx = eng().fromFloats({c.M, c.K}, x, c.xType), tw = eng().fromFloats({c.N, c.K}, w, DType::F16);
  Tensor tb = c.bias ? eng().fromFloats({c.N}, b) : Tensor();
  GuardedOutput y(eng(), {c.M, c.N}, c.yType);
  Recorder rec(eng());
  linear(rec, tx, tw, tb, y.tensor(), c.act);
  rec.run();
  const auto rounded = linearRef(roundToHalf(x), roundToHalf(w), b, 1, c.M, c.N, c.K, false, c.act);
  if (c.yType == DType::F32) expectClose(y.read(), rounded, 1e-10 * std::max<int64_t>(1, c.K / 16), 1e-4, "coopmat");
  else expectClose(y.read(), rounded, 2e-6, 5e-2, "coopmat, f16 out");
  expectClose(y.read(), linearRef(x, w, b, 1, c.M, c.N, c.K, false, c.act), 2e-6, 5e-2, "coopmat vs fp32 inputs");
  y.expectAllWritten();
}

INSTANTIATE_TEST_SUITE_P(
    OddShapes, CoopMatShapes,
    ::testing::Values(Case{7, 61, 64, false, Activation::None, DType::F32, DType::F32},
                      Case{61, 7, 61, true, Activation::None, DType::F32, DType::F32},
                      Case{257, 131, 256, true, Activation::Gelu, DType::F32, DType::F32},
                      Case{1, 1, 1, false, Activation::None, DType::F32, DType::F32},
                      Case{130, 768, 518, true, Activation::Silu, DType::F16, DType::F32},
                      Case{45, 70, 384, true, Activation::None, DType::F16, DType::F16},
                      Case{33, 65, 130, false, Activation::Sigmoid, DType::F32, DType::F16}));

TEST_F(CoopMatTest, BatchedWeights) {
  const int64_t B = 3, M = 29, N = 37, K = 44;
  auto x = randomUniform(B * M * K, -1, 1, 34), w = randomUniform(B * N * K, -1, 1, 35);
  Tensor tx = eng().fromFloats({B, M, K}, x), tw = eng().fromFloats({B, N, K}, w, DType::F16);
  GuardedOutput y(eng(), {B, M, N});
  Recorder rec(eng());
  linear(rec, tx, tw, Tensor(), y.tensor());
  rec.run();
  expectClose(y.read(), linearRef(roundToHalf(x), roundToHalf(w), {}, B, M, N, K, true, Activation::None), 1e-10, 1e-4,
              "batched");
  y.expectAllWritten();
}

// Activations beyond fp16's range saturate at +-65504 when they are staged (never inf).
TEST_F(CoopMatTest, ActivationsBeyondFp16Saturate) {
  const int64_t M = 5, N = 8, K = 16;
  std::vector<float> x(M * K, 0.0f), w(N * K, 0.0f);
  for (int64_t m = 0; m < M; ++m) x[m * K] = (m % 2 ? -1.0f : 1.0f) * 1e6f;
  for (int64_t n = 0; n < N; ++n) w[n * K] = 1.0f / 1024;
  Tensor tx = eng().fromFloats({M, K}, x), tw = eng().fromFloats({N, K}, w, DType::F16);
  GuardedOutput y(eng(), {M, N});
  Recorder rec(eng());
  linear(rec, tx, tw, Tensor(), y.tensor());
  rec.run();
  const auto out = y.read();
  for (int64_t m = 0; m < M; ++m)
    for (int64_t n = 0; n < N; ++n) EXPECT_EQ(out[m * N + n], (m % 2 ? -1.0f : 1.0f) * 65504.0f / 1024) << m << "," << n;
}

// Attention of fp16 layers (shaders/attention_coopmat.comp): q, k, v rounded to fp16, scores and
// output in fp32, the probabilities rounded to fp16 before they multiply v. Against float64 on
// the rounded inputs the error is that last rounding (relative 2^-11 per probability: measured
// NMSE 1.3e-8 .. 3.1e-8 on lavapipe 26.1, max abs 3.5e-4); thresholds 1e-6.
struct AttentionCase {
  int64_t B, Nq, Nk;
  int heads, dh;
  bool causal;
};

class CoopMatAttention : public EngineTest, public ::testing::WithParamInterface<AttentionCase> {};

TEST_P(CoopMatAttention, MatchesFloat64OnFp16Inputs) {
  const AttentionCase c = GetParam();
  const int64_t D = int64_t(c.heads) * c.dh;
  auto q = randomNormal(c.B * c.Nq * D, 0, 1, 41), kv = randomNormal(c.B * c.Nk * 2 * D, 0, 1, 42);
  Tensor tq = eng().fromFloats({c.B, c.Nq, D}, q), tkv = eng().fromFloats({c.B, c.Nk, 2 * D}, kv);
  GuardedOutput out(eng(), {c.B, c.Nq, D});
  Recorder rec(eng());
  attention(rec, {tq, 0}, {tkv, 0}, {tkv, D}, {out.tensor(), 0}, c.heads, c.dh, c.causal, 0.0f, /*fp16Layer=*/true);
  rec.run();
  const auto rq = roundToHalf(q), rkv = roundToHalf(kv);
  const double scale = 1.0 / std::sqrt(double(c.dh));
  expectClose(out.read(), attentionRef(rq, D, 0, rkv, 2 * D, 0, rkv, 2 * D, D, c.B, c.Nq, c.Nk, c.heads, c.dh, c.causal, scale),
              1e-6, 2e-2, "coopmat attention");
  out.expectAllWritten();
}

// Odd query and key counts (tails of the query block and of the key block), causal masks, heads
// of 32 and 64, one key.
INSTANTIATE_TEST_SUITE_P(Shapes, CoopMatAttention,
                         ::testing::Values(AttentionCase{1, 61, 61, 2, 32, false}, AttentionCase{2, 7, 45, 3, 64, false},
                                           AttentionCase{1, 257, 257, 2, 64, false}, AttentionCase{2, 61, 61, 2, 32, true},
                                           AttentionCase{1, 130, 130, 1, 64, true}, AttentionCase{1, 5, 1, 1, 32, false}));

// The q / k norm and RoPE inside the cooperative-matrix kernel (attention_coopmat.comp's *_prep
// variants; SPAR's and DINOv3's fp16 layers): prepared in fp32, then rounded to fp16, against
// float64 preparation rounded the same way. One dispatch, odd token counts, a prefix, causal.
TEST_F(CoopMatTest, AttentionPreparesQAndK) {
  for (const bool causal : {false, true}) {
    const int64_t B = 2, N = 45, prefix = 3;
    const int heads = 2, dh = 32;
    const int64_t D = int64_t(heads) * dh;
    const auto qkv = randomNormal(B * N * 3 * D, 0, 1, 51), w = randomUniform(2 * dh, 0.5f, 1.5f, 52);
    const auto angles = randomUniform((N - prefix) * dh, -3, 3, 53);
    std::vector<float> sines, cosines;
    for (float a : angles) sines.push_back(std::sin(a)), cosines.push_back(std::cos(a));
    QkPrep prep;
    prep.normWeight = eng().fromFloats({2, dh}, w);
    prep.ropeSin = eng().fromFloats({N - prefix, dh}, sines);
    prep.ropeCos = eng().fromFloats({N - prefix, dh}, cosines);
    prep.ropePrefix = prefix;
    const Tensor t = eng().fromFloats({B, N, 3 * D}, qkv);
    GuardedOutput out(eng(), {B, N, D});
    Recorder rec(eng());
    attention(rec, {t, 0}, {t, D}, {t, 2 * D}, {out.tensor(), 0}, heads, dh, causal, 0.0f, /*fp16Layer=*/true, prep);
    rec.run();
    EXPECT_EQ(rec.lastRunTotal().dispatches, 1u);
    const auto prepared = prepareQkRef(qkv, B, N, heads, dh, w, prep.normEps, sines, cosines, prefix);
    const auto rounded = roundToHalf(std::vector<float>(prepared.begin(), prepared.end()));
    expectClose(out.read(),
                attentionRef(rounded, 3 * D, 0, rounded, 3 * D, D, rounded, 3 * D, 2 * D, B, N, N, heads, dh, causal,
                             1.0 / std::sqrt(double(dh))),
                1e-6, 2e-2, causal ? "coopmat prepared, causal" : "coopmat prepared");
    out.expectAllWritten();
  }
}

// Stiff: logits of +-1e4 (q, k of 100 in fp16) and one dominant key per query stay finite and
// pick the right value row.
TEST_F(CoopMatTest, AttentionOneKeyDominates) {
  const int64_t N = 37;
  const int dh = 32;
  std::vector<float> q(N * dh, 0.0f), kv(N * 2 * dh, 0.0f);
  for (int64_t i = 0; i < N; ++i) {
    q[i * dh + (i % dh)] = 100.0f;                       // query i points along axis i % dh
    kv[i * 2 * dh + (i % dh)] = i < dh ? 100.0f : -100.0f;  // key i (< dh) matches query i
    for (int c = 0; c < dh; ++c) kv[i * 2 * dh + dh + c] = float(i);  // value row i is i
  }
  Tensor tq = eng().fromFloats({1, N, dh}, q), tkv = eng().fromFloats({1, N, 2 * dh}, kv);
  GuardedOutput out(eng(), {1, N, dh});
  Recorder rec(eng());
  attention(rec, {tq, 0}, {tkv, 0}, {tkv, dh}, {out.tensor(), 0}, 1, dh, false, 0.0f, true);
  rec.run();
  const auto o = out.read();
  for (int64_t i = 0; i < dh; ++i)
    for (int c = 0; c < dh; ++c) ASSERT_NEAR(o[i * dh + c], float(i), 1e-2f) << "query " << i;
  for (float x : o) ASSERT_TRUE(std::isfinite(x));
}

// Every workgroup shape the tuner tries (engine/kernel_tuner.h), and the smallest one, forced in
// turn (KernelTuning::coopMatTiles), computes the same product.
TEST_F(CoopMatTest, EveryWorkgroupShapeMatchesFloat64) {
  const int64_t M = 77, N = 150, K = 72;
  auto x = randomUniform(M * K, -1, 1, 51), w = randomUniform(N * K, -1, 1, 52), b = randomUniform(N, -1, 1, 53);
  Tensor tx = eng().fromFloats({M, K}, x), tw = eng().fromFloats({N, K}, w, DType::F16), tb = eng().fromFloats({N}, b);
  const auto ref = linearRef(roundToHalf(x), roundToHalf(w), b, 1, M, N, K, false, Activation::Gelu);
  const KernelTuning saved = eng().options().tuning;
  std::vector<std::array<int, 6>> shapes = {{1, 1, 1, 1, 1, 1}, {1, 1, 1, 1, 1, 0}};
  for (const CoopMatTiles& c : coopMatTileCandidates(eng().caps(), eng().plan().coop))
    shapes.push_back({c.wm, c.wn, c.sgM, c.sgN, c.kSteps, c.pipelined ? 1 : 0});
  ASSERT_GE(shapes.size(), 4u);
  for (const auto& shape : shapes) {
    KernelTuning t = saved;
    t.coopMatTiles = shape;
    eng().setTuning(t);
    GuardedOutput y(eng(), {M, N});
    Recorder rec(eng());
    linear(rec, tx, tw, tb, y.tensor(), Activation::Gelu);
    rec.run();
    expectClose(y.read(), ref, 1e-10, 1e-4, "coopmat " + eng().plan().coop.text());
    y.expectAllWritten();
  }
  eng().setTuning(saved);
}

// Measured at first use (SPAR_MEASURE_KERNELS=1 on this CPU device): the cooperative-matrix
// workgroup shape is chosen among the candidates, kept in kernel-choice.json and read back.
TEST_F(CoopMatTest, WorkgroupShapeMeasuredAndCached) {
  const std::filesystem::path dir = scratchDir("coopmat_tuner");
  EngineOptions o;
  o.validation = true;
  o.tuning.kernels = "coopmat";
  o.tuning.measureKernels = true;
  o.pipelineCacheFile = (dir / "pipelines.bin").string();
  std::string chosen;
  {
    Engine e(o);
    EXPECT_NE(e.plan().source.find("measured now"), std::string::npos) << e.plan().source;
    chosen = e.plan().coop.text();
    EXPECT_EQ(e.device().validationMessageCount(), 0u);
  }
  std::ifstream in(kernelChoiceFile(o.pipelineCacheFile));
  const auto j = nlohmann::json::parse(in);
  EXPECT_GE(j.begin().value()["coopmat"]["candidates"].size(), 3u);
  Engine e(o);
  EXPECT_NE(e.plan().source.find("kernel-choice.json"), std::string::npos) << e.plan().source;
  EXPECT_EQ(e.plan().coop.text(), chosen);
}

}  // namespace
}  // namespace spar::test
