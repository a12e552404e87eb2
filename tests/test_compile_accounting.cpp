// What the engine compiles and what it learns about it: pipelines created at run() for the
// whole batch, one pipeline per texel signature, the same driver-visible state for every
// dispatch of a pipeline (so a CPU driver compiles it once), the empty dispatch that keeps
// a driver's build apart from compute, and how later builds are classified.
// CTest runs this executable with Mesa's shader disk cache off (tests/CMakeLists.txt), so a
// first build here is a real compile, never a reload.
#include "engine/ops/linear.h"
#include "engine/pipeline_stats.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

const Pipeline* pipelineNamed(Engine& e, const std::string& kernelName, const std::string& signature) {
  for (const Pipeline* p : e.pipelines().pipelines())
    if (p->kernel->name == kernelName && p->signature == signature) return p;
  return nullptr;
}

// One GEMM pipeline serves every shape: buffer sizes that are and are not powers of two,
// views whose byte size has zero bits 8-15 (256 x 256 floats) and odd ones. The driver sees
// one texel state, builds once and never again.
TEST_F(EngineTest, OnePipelineOneStateOneBuildAcrossShapes) {
  const int64_t shapes[][3] = {{64, 64, 64}, {256, 24, 256}, {61, 33, 20}, {128, 128, 64}, {7, 5, 16}, {300, 40, 128}};
  std::string kernelName;
  for (const auto& s : shapes) {
    const int64_t M = s[0], N = s[1], K = s[2];
    Tensor x = eng().fromFloats({M, K}, randomUniform(M * K, -1, 1, 7));
    Tensor w = eng().fromFloats({N, K}, randomUniform(N * K, -1, 1, 8));
    Tensor b = eng().fromFloats({N}, randomUniform(N, -1, 1, 9));
    Tensor y = eng().tensor({M, N});
    Recorder rec(eng(), true);
    linear(rec, x, w, b, y, Activation::Silu);
    rec.run();
    ASSERT_EQ(rec.timings().size(), 1u);
    if (kernelName.empty()) kernelName = rec.timings()[0].pipeline;
    EXPECT_EQ(rec.timings()[0].pipeline, kernelName) << "shape " << M << "x" << N << "x" << K;
  }
  const Pipeline* p = pipelineNamed(eng(), kernelName, "f32x4,f32x4,f32x1");
  ASSERT_NE(p, nullptr) << kernelName;
  EXPECT_EQ(p->stats.dispatches, 6);
  EXPECT_EQ(p->stats.texelStates.size(), 1u) << "the driver saw different texel binding states";
  EXPECT_EQ(p->stats.pushValues.size(), 6u);
  EXPECT_EQ(p->stats.rebuildCount(), 0) << p->stats.buildMs << " ms of builds";
  if (eng().caps().isLlvmpipe()) {
    EXPECT_EQ(p->stats.builds, 1) << "llvmpipe compiles at the first dispatch";
  }
}

// The build happens in the empty dispatch before the first real one: the first run shows it
// apart from compute, the second run has none.
TEST_F(EngineTest, BuildTimeIsKeptApartFromCompute) {
  const int64_t M = 37, N = 29, K = 44;  // K % 4 == 0, N odd: a variant no other test made here
  Tensor x = eng().fromFloats({M, K}, randomUniform(M * K, -1, 1, 11));
  Tensor w = eng().fromFloats({N, K}, randomUniform(N * K, -1, 1, 12));
  Tensor y = eng().tensor({M, N});
  Recorder rec(eng(), true);
  linear(rec, x, w, Tensor(), y, Activation::QuickGelu);
  rec.run();
  ASSERT_EQ(rec.timings().size(), 1u);
  const double firstBuild = rec.totalBuildMs(), firstCompute = rec.totalMs();
  linear(rec, x, w, Tensor(), y, Activation::QuickGelu);
  rec.run();
  EXPECT_EQ(rec.totalBuildMs(), 0.0);
  if (eng().caps().isLlvmpipe()) {
    EXPECT_GT(firstBuild, 10.0) << "a compile of the GEMM takes far longer than this";
    EXPECT_LT(firstCompute, firstBuild) << "the compile leaked into the dispatch's time";
  }
}

// Creation waits for run(): recording only describes the work, and run() creates every
// pipeline the batch needs at once.
TEST_F(EngineTest, PipelinesAreCreatedForTheWholeBatchAtRun) {
  const int64_t M = 9, N = 13, K = 12;
  Tensor x = eng().fromFloats({M, K}, randomUniform(M * K, -1, 1, 13));
  Tensor w = eng().fromFloats({N, K}, randomUniform(N * K, -1, 1, 14));
  Tensor b = eng().fromFloats({N}, randomUniform(N, -1, 1, 15));
  std::vector<Tensor> ys;
  const size_t before = eng().pipelines().pipelines().size();
  Recorder rec(eng(), true);
  for (Activation act : {Activation::None, Activation::Gelu, Activation::Sigmoid, Activation::Relu}) {
    ys.push_back(eng().tensor({M, N}));
    linear(rec, x, w, b, ys.back(), act);
  }
  EXPECT_EQ(eng().pipelines().pipelines().size(), before) << "nothing is created while recording";
  rec.run();
  const auto all = eng().pipelines().pipelines();
  ASSERT_GE(all.size(), before + 1);
  for (size_t i = before; i < all.size(); ++i) {
    EXPECT_GT(all[i]->stats.createMs, 0.0) << all[i]->name;
    EXPECT_NE(all[i]->handle, VK_NULL_HANDLE);
  }
  // The results are those of the activations asked for (each dispatch got its own pipeline).
  const auto xv = eng().download(x), wv = eng().download(w), bv = eng().download(b);
  const Activation acts[] = {Activation::None, Activation::Gelu, Activation::Sigmoid, Activation::Relu};
  for (int a = 0; a < 4; ++a) {
    std::vector<double> ref(M * N);
    for (int64_t m = 0; m < M; ++m)
      for (int64_t n = 0; n < N; ++n) {
        double s = bv[n];
        for (int64_t k = 0; k < K; ++k) s += double(xv[m * K + k]) * wv[n * K + k];
        ref[m * N + n] = activateRef(s, acts[a]);
      }
    expectClose(eng().download(ys[a]), ref, 1e-10, 1e-5, "activation " + std::to_string(a));
  }
}

// Weights of another texel format get their own pipeline (llvmpipe would otherwise compile a
// second variant of the first, whose key Mesa's disk cache cannot find again next time).
TEST_F(EngineTest, EachTexelSignatureHasItsOwnPipeline) {
  if (!eng().caps().supportsFp16Storage()) GTEST_SKIP() << "device without fp16 storage";
  const int64_t M = 17, N = 11, K = 20;
  Tensor x = eng().fromFloats({M, K}, randomUniform(M * K, -1, 1, 16));
  const auto wv = randomUniform(N * K, -1, 1, 17);
  Tensor w32 = eng().fromFloats({N, K}, wv), w16 = eng().fromFloats({N, K}, wv, DType::F16);
  Tensor y32 = eng().tensor({M, N}), y16 = eng().tensor({M, N});
  Recorder rec(eng(), true);
  linear(rec, x, w32, Tensor(), y32);
  linear(rec, x, w16, Tensor(), y16);
  rec.run();
  ASSERT_EQ(rec.timings().size(), 2u);
  EXPECT_NE(rec.timings()[0].pipeline, rec.timings()[1].pipeline);
  EXPECT_NE(rec.timings()[1].pipeline.find("f16x4"), std::string::npos) << rec.timings()[1].pipeline;
  expectClose(eng().download(y16), toDouble(eng().download(y32)), 1e-5, 1e-2, "fp16 weights");
}

DispatchObservation seen(double buildMs, const std::string& state, const std::string& push) {
  return {buildMs, 1.0, state, push};
}

// Why a later build happened: a state not seen before, push-constant values not seen before
// (a driver that specialises on them), or neither (evicted). Short stretches after a long
// first build are the thread being preempted, not builds.
TEST(PipelineStats, ClassifiesBuilds) {
  PipelineStats s;
  BuildCause c{};
  EXPECT_TRUE(s.observe(seen(100, "--", "a"), &c));
  EXPECT_EQ(c, BuildCause::FirstUse);
  EXPECT_FALSE(s.observe(seen(0.01, "--", "b"), &c));  // built already: no build
  EXPECT_FALSE(s.observe(seen(5, "--", "a"), &c));     // 5 ms after a 100 ms compile: noise
  EXPECT_TRUE(s.observe(seen(90, "p-", "a"), &c));
  EXPECT_EQ(c, BuildCause::NewTexelState);
  EXPECT_TRUE(s.observe(seen(95, "--", "c"), &c));
  EXPECT_EQ(c, BuildCause::NewPushValues);
  EXPECT_TRUE(s.observe(seen(80, "--", "a"), &c));
  EXPECT_EQ(c, BuildCause::Repeat);
  EXPECT_EQ(s.builds, 4);
  EXPECT_EQ(s.compiles, 4);
  EXPECT_EQ(s.rebuildCount(), 3);
  EXPECT_EQ(s.dispatches, 6);
  EXPECT_DOUBLE_EQ(s.buildMs, 100 + 90 + 95 + 80);
  EXPECT_DOUBLE_EQ(s.gpuMs, 6.0);
  EXPECT_EQ(s.rebuilds[int(BuildCause::NewTexelState)], 1);
  EXPECT_EQ(s.rebuilds[int(BuildCause::NewPushValues)], 1);
  EXPECT_EQ(s.rebuilds[int(BuildCause::Repeat)], 1);
}

}  // namespace
}  // namespace spar::test
