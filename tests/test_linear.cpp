// Linear layer (shaders/gemm.comp, and gemm_lanes.comp where the plan says, via engine/ops/linear.cpp) against a float64 reference.
#include "engine/ops/linear.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "engine/kernel_plan.h"
#include "engine/ops/cpu_tiles.h"
#include "tests/quantized_weights.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

struct LinearCase {
  int64_t M, N, K;
  bool bias;
  Activation act;
};

class LinearTest : public EngineTest, public ::testing::WithParamInterface<LinearCase> {};

// One product of random values in [-1, 1] (seeds seed .. seed + 2) against float64.
void expectLinearMatches(Engine& engine, const LinearCase& c, uint32_t seed, const std::string& what) {
  auto x = randomUniform(c.M * c.K, -1, 1, seed), w = randomUniform(c.N * c.K, -1, 1, seed + 1);
  auto b = c.bias ? randomUniform(c.N, -1, 1, seed + 2) : std::vector<float>{};
  Tensor tx = engine.fromFloats({c.M, c.K}, x), tw = engine.fromFloats({c.N, c.K}, w);
  Tensor tb = c.bias ? engine.fromFloats({c.N}, b) : Tensor();
  GuardedOutput y(engine, {c.M, c.N});
  Recorder rec(engine);
  linear(rec, tx, tw, tb, y.tensor(), c.act);
  rec.run();
  const std::string shape = std::to_string(c.M) + "x" + std::to_string(c.N) + "x" + std::to_string(c.K);
  expectClose(y.read(), linearRef(x, w, b, 1, c.M, c.N, c.K, false, c.act), 1e-10 * std::max<int64_t>(1, c.K / 16), 1e-4,
              what + " " + shape);
  y.expectAllWritten();
}

TEST_P(LinearTest, MatchesFloat64Reference) { expectLinearMatches(eng(), GetParam(), 1, "linear"); }

INSTANTIATE_TEST_SUITE_P(
    OddShapes, LinearTest,
    ::testing::Values(LinearCase{7, 61, 64, false, Activation::None}, LinearCase{61, 7, 61, true, Activation::None},
                      LinearCase{257, 131, 256, true, Activation::None}, LinearCase{1, 1, 1, false, Activation::None},
                      LinearCase{33, 65, 130, true, Activation::Gelu}, LinearCase{19, 40, 24, true, Activation::QuickGelu},
                      LinearCase{64, 17, 20, false, Activation::Silu}, LinearCase{9, 300, 12, true, Activation::Sigmoid},
                      LinearCase{21, 35, 9, true, Activation::Relu},
                      LinearCase{130, 768, 518, true, Activation::None}));

// SwiftShader's GEMM (gemm_lanes.comp: a subgroup's lanes split k, combined by subgroupAdd;
// its constants written into the module, engine/spirv_freeze.h) forced on this device, through
// texel buffers and through storage buffers (SwiftShader's inputs): K below, at and past the
// subgroup's width and not a multiple of it (the masked last trip), M and N past a block's
// edge, bias and every activation. Where the device has no subgroup arithmetic with full
// subgroups (some device-limit profiles) the plan must refuse it.
TEST_F(EngineTest, LinearLanesSplitKMatchesFloat64) {
  withLanesKernelsForced(eng(), [&](const std::string& inputs) {
    for (const LinearCase c : {LinearCase{7, 61, 64, false, Activation::None}, LinearCase{61, 7, 61, true, Activation::None},
                               LinearCase{1, 1, 1, false, Activation::None}, LinearCase{33, 65, 130, true, Activation::Gelu},
                               LinearCase{19, 40, 3, true, Activation::QuickGelu}, LinearCase{64, 17, 20, false, Activation::Silu},
                               LinearCase{9, 30, 12, true, Activation::Sigmoid}, LinearCase{21, 35, 9, true, Activation::Relu}}) {
      expectLinearMatches(eng(), c, 11, "lanes, " + inputs + " inputs,");
    }
  });
}

// The residual add fused into the GEMM (linear's accumulate, every GEMM kernel's ACCUMULATE):
// y = y0 + act(x W^T + b) against float64, y0 of its own size. Odd shapes past a block's edge,
// bias and an activation, a quantized weight, an output the device cannot bind where it starts
// (the add then runs apart), through this device's plan and SwiftShader's lanes GEMM; the GPU
// family and the device profiles run this program too (gpu_family.test_linear, ...).
// With scaled, a layer scale in the epilogue too (layerScaleEpilogue, gemm_epilogue.glsl's
// SCALED): y = y0 + gamma * act(x W^T + b), gammas of DINOv3's size (1e-5 .. 1) and of both signs.
void expectAccumulates(Engine& engine, const LinearCase& c, int bits, int64_t offset, const std::string& what,
                       bool scaled = false) {
  const auto x = randomUniform(c.M * c.K, -1, 1, 41), w = randomUniform(c.N * c.K, -1, 1, 42);
  const auto b = c.bias ? randomUniform(c.N, -1, 1, 43) : std::vector<float>{};
  const auto y0 = randomUniform(c.M * c.N, -2, 2, 44);
  std::vector<float> gamma = randomUniform(c.N, -5, 0, 45);
  for (size_t n = 0; n < gamma.size(); ++n) gamma[n] = float((n % 2 ? -1 : 1) * std::pow(10.0, gamma[n]));
  const QuantizedMatrix q = bits ? quantizeReference(w, c.N, c.K, bits) : QuantizedMatrix{};
  const Tensor tx = engine.fromFloats({c.M, c.K}, x);
  const Tensor tw = bits ? quantizedTensor(engine, q, c.N, c.K, bits) : engine.fromFloats({c.N, c.K}, w);
  const Tensor plainBias = c.bias ? engine.fromFloats({c.N}, b) : Tensor();
  const Tensor tb = scaled ? layerScaleEpilogue(engine, plainBias, engine.fromFloats({c.N}, gamma)) : plainBias;
  const Tensor whole = engine.tensor({offset + c.M * c.N});
  const Tensor y = whole.view(offset, {c.M, c.N});
  engine.upload(y, y0);
  Recorder rec(engine);
  linear(rec, tx, tw, tb, y, c.act, /*accumulate=*/true);
  rec.run();
  const bool viaFp16 = bits && engine.plan().quantizedGemm() == KernelFamily::CoopMat;
  std::vector<double> ref = viaFp16 ? linearRef(roundToHalf(x), roundToHalf(q.values), b, 1, c.M, c.N, c.K, false, c.act)
                            : linearRef(x, bits ? q.values : w, b, 1, c.M, c.N, c.K, false, c.act);
  for (size_t i = 0; i < ref.size(); ++i) ref[i] = y0[i] + (scaled ? double(gamma[i % size_t(c.N)]) : 1.0) * ref[i];
  expectClose(engine.download(y), ref, 1e-10 * std::max<int64_t>(1, c.K / 16), 1e-4, what);
}

TEST_F(EngineTest, LinearAccumulateAddsToTheOutput) {
  const LinearCase plain{61, 7, 61, true, Activation::None}, gelu{33, 65, 130, true, Activation::Gelu};
  expectAccumulates(eng(), plain, 0, 0, "accumulate 61x7x61");
  expectAccumulates(eng(), gelu, 0, 0, "accumulate 33x65x130 gelu");
  expectAccumulates(eng(), {7, 61, 96, false, Activation::None}, 8, 0, "accumulate q8 7x61x96");
  expectAccumulates(eng(), plain, 0, 1, "accumulate into an output one float past an aligned start");
  withLanesKernelsForced(eng(), [&](const std::string& inputs) {
    expectAccumulates(eng(), gelu, 0, 0, "lanes, " + inputs + " inputs, accumulate 33x65x130 gelu");
  });
}

// DINOv3's layer-scaled residual branches, x += gamma * fc(h), as one GEMM: with and without a
// bias, an activation, a quantized weight, an output bound past an aligned start, SwiftShader's
// lanes GEMM; bad (bias, scale) tensors refused.
TEST_F(EngineTest, LinearLayerScaleInTheEpilogue) {
  expectAccumulates(eng(), {61, 7, 61, true, Activation::None}, 0, 0, "layer scale 61x7x61", true);
  expectAccumulates(eng(), {33, 65, 130, false, Activation::Gelu}, 0, 0, "layer scale, no bias, 33x65x130 gelu", true);
  expectAccumulates(eng(), {7, 61, 96, true, Activation::None}, 8, 0, "layer scale q8 7x61x96", true);
  expectAccumulates(eng(), {61, 7, 61, true, Activation::None}, 0, 1, "layer scale, output past an aligned start", true);
  withLanesKernelsForced(eng(), [&](const std::string& inputs) {
    expectAccumulates(eng(), {33, 65, 130, true, Activation::Gelu}, 0, 0, "lanes, " + inputs + " inputs, layer scale", true);
  });
  const Tensor gamma = eng().fromFloats({5}, std::vector<float>(5, 0.5f));
  EXPECT_THROW(layerScaleEpilogue(eng(), eng().tensor({4}), gamma), Error);
  const Tensor x = eng().tensor({3, 8}), w = eng().tensor({5, 8}), y = eng().tensor({3, 5});
  Recorder rec(eng());
  EXPECT_THROW(linear(rec, x, w, eng().tensor({4, 4}), y), Error);  // (bias, scale) texels of 4 columns for 5
}

// llvmpipe's plan shares a workgroup's columns among its subgroup's lanes (gemm.comp's
// SHARED_COLUMNS, engine/ops/linear.cpp chooseGemmTiles; the other tests here: 16 columns), from
// 2^28 multiply-adds 32 columns, 16 where N is narrower: odd M and N past the last block's edge, fp32 and q8 weights (the thresholds of the
// other fp32 and quantized tests). Checked against float64 on every column of sampled rows
// (every 37th, and the last block's): the full reference is 2^28 multiply-adds a case. Elsewhere (GPU family, device profiles without full
// subgroups) the same products take kernels the other tests cover, at a cold compile each.
void expectSampledRows(Engine& engine, const Tensor& y, const std::vector<float>& x, const std::vector<float>& w,
                       const std::vector<float>& b, int64_t M, int64_t N, int64_t K, Activation act, double maxAbs,
                       double maxAbsPerPeak, const std::string& what) {
  std::vector<int64_t> rows;
  for (int64_t m = 0; m < M; m += 37) rows.push_back(m);
  for (int64_t m = std::max<int64_t>(0, M - 40); m < M; ++m)
    if (m % 37) rows.push_back(m);
  std::vector<float> xs, got;
  const std::vector<float> all = engine.download(y);
  for (int64_t m : rows) {
    xs.insert(xs.end(), x.begin() + m * K, x.begin() + (m + 1) * K);
    got.insert(got.end(), all.begin() + m * N, all.begin() + (m + 1) * N);
  }
  const auto ref = linearRef(xs, w, b, 1, int64_t(rows.size()), N, K, false, act);
  double peak = 0;
  for (double v : ref) peak = std::max(peak, std::abs(v));
  expectClose(got, ref, 1e-10 * std::max<int64_t>(1, K / 16), maxAbs + maxAbsPerPeak * std::max(1.0, peak), what);
}

TEST_F(EngineTest, LinearLargeProductsPastEveryEdge) {
  if (!ops::cpuLanesShareFetches(eng().caps()) || eng().plan().gemm != KernelFamily::CpuBlocks)
    GTEST_SKIP() << "the plan shares no columns on this device";
  {
    const int64_t M = 521, N = 1003, K = 516;  // 2^28.006 multiply-adds
    ASSERT_GE(double(M) * N * K, double(1 << 28));
    auto x = randomUniform(M * K, -1, 1, 31), w = randomUniform(N * K, -1, 1, 32), b = randomUniform(N, -1, 1, 33);
    Tensor tx = eng().fromFloats({M, K}, x), tw = eng().fromFloats({N, K}, w), tb = eng().fromFloats({N}, b);
    GuardedOutput y(eng(), {M, N});
    Recorder rec(eng());
    linear(rec, tx, tw, tb, y.tensor(), Activation::Gelu);
    rec.run();
    expectSampledRows(eng(), y.tensor(), x, w, b, M, N, K, Activation::Gelu, 1e-4, 0, "521x1003x516");
    y.expectAllWritten();
  }
  // 20 columns: the narrow block; q8 weights dequantized as they are fetched
  const int64_t M = 104863, N = 20, K = 128;
  ASSERT_GE(double(M) * N * K, double(1 << 28));
  const auto x = randomUniform(M * K, -1, 1, 34);
  const QuantizedMatrix q = quantizeReference(randomUniform(N * K, -1, 1, 35), N, K, 8);
  Tensor tx = eng().fromFloats({M, K}, x), tw = quantizedTensor(eng(), q, N, K, 8);
  GuardedOutput y(eng(), {M, N});
  Recorder rec(eng());
  linear(rec, tx, tw, Tensor(), y.tensor());
  rec.run();
  expectSampledRows(eng(), y.tensor(), x, q.values, {}, M, N, K, Activation::None, 0, 1e-6, "q8 104863x20x128");
  y.expectAllWritten();
}

TEST_F(EngineTest, LinearBatchedWeights) {
  const int64_t B = 3, M = 29, N = 37, K = 44;
  auto x = randomUniform(B * M * K, -1, 1, 4), w = randomUniform(B * N * K, -1, 1, 5);
  Tensor tx = eng().fromFloats({B, M, K}, x), tw = eng().fromFloats({B, N, K}, w);
  GuardedOutput y(eng(), {B, M, N});
  Recorder rec(eng());
  linear(rec, tx, tw, Tensor(), y.tensor());
  rec.run();
  expectClose(y.read(), linearRef(x, w, {}, B, M, N, K, true, Activation::None), 1e-10, 1e-4, "batched");
  y.expectAllWritten();
}

TEST_F(EngineTest, LinearLeadingDimsAreRows) {
  const int64_t B = 2, T = 13, N = 24, K = 16;
  auto x = randomUniform(B * T * K, -1, 1, 6), w = randomUniform(N * K, -1, 1, 7);
  Tensor tx = eng().fromFloats({B, T, K}, x), tw = eng().fromFloats({N, K}, w);
  GuardedOutput y(eng(), {B, T, N});
  Recorder rec(eng());
  linear(rec, tx, tw, Tensor(), y.tensor());
  rec.run();
  expectClose(y.read(), linearRef(x, w, {}, 1, B * T, N, K, false, Activation::None), 1e-10, 1e-4, "rows");
}

// fp16 weights and activations, fp32 accumulation: exact on fp16-rounded inputs up to
// fp32 accumulation error, and within fp16 rounding of the fp32 reference.
TEST_F(EngineTest, LinearFp16StorageAccumulatesInFp32) {
  if (!eng().caps().supportsFp16Storage()) GTEST_SKIP() << "device without fp16 storage";
  const int64_t M = 45, N = 70, K = 384;
  auto x = randomUniform(M * K, -1, 1, 8), w = randomUniform(N * K, -1, 1, 9), b = randomUniform(N, -1, 1, 10);
  Tensor tx = eng().fromFloats({M, K}, x, DType::F16), tw = eng().fromFloats({N, K}, w, DType::F16);
  Tensor tb = eng().fromFloats({N}, b, DType::F16);
  GuardedOutput y(eng(), {M, N}, DType::F32);
  GuardedOutput y16(eng(), {M, N}, DType::F16);
  Recorder rec(eng());
  linear(rec, tx, tw, tb, y.tensor());
  linear(rec, tx, tw, tb, y16.tensor());
  rec.run();
  auto refRounded = linearRef(roundToHalf(x), roundToHalf(w), roundToHalf(b), 1, M, N, K, false, Activation::None);
  auto refExact = linearRef(x, w, b, 1, M, N, K, false, Activation::None);
  expectClose(y.read(), refRounded, 1e-10, 1e-4, "f16 in, f32 out vs rounded");
  expectClose(y.read(), refExact, 2e-6, 5e-2, "f16 in, f32 out vs fp32");
  expectClose(y16.read(), refExact, 2e-6, 5e-2, "f16 in, f16 out vs fp32");
  y16.expectAllWritten();
}

// Values beyond 65504 saturate to the largest finite fp16 instead of becoming inf.
TEST_F(EngineTest, LinearFp16OutputOverflowSaturates) {
  if (!eng().caps().supportsFp16Storage()) GTEST_SKIP() << "device without fp16 storage";
  const int64_t M = 5, N = 8, K = 4;
  std::vector<float> x(M * K, 300.0f), w(N * K, 0);
  for (int64_t n = 0; n < N; ++n) w[n * K] = (n % 2 ? -1.0f : 1.0f) * float(n + 1) * 60.0f;  // |y| up to 144000
  Tensor tx = eng().fromFloats({M, K}, x, DType::F16), tw = eng().fromFloats({N, K}, w, DType::F16);
  GuardedOutput y(eng(), {M, N}, DType::F16);
  Recorder rec(eng());
  linear(rec, tx, tw, Tensor(), y.tensor());
  rec.run();
  auto out = y.read();
  for (int64_t m = 0; m < M; ++m)
    for (int64_t n = 0; n < N; ++n) {
      const double ref = 300.0 * (n % 2 ? -1.0 : 1.0) * (n + 1) * 60.0;
      const float got = out[m * N + n];
      ASSERT_TRUE(std::isfinite(got)) << "overflow to inf at n=" << n;
      if (std::abs(ref) > 65504) EXPECT_EQ(std::abs(got), 65504.0f);
      else EXPECT_NEAR(got, ref, std::abs(ref) * 1e-3);
      EXPECT_EQ(got < 0, ref < 0);
    }
}

// A weight larger than lavapipe's 128 MiB storage-buffer range (the shape of SPAR's
// semantic head, 16384 x 3072 fp32 = 192 MiB) works through texel bindings.
TEST_F(EngineTest, LinearWeightAboveStorageRange) {
  const int64_t M = 3, N = 16384, K = 3072;
  auto x = randomUniform(M * K, -1, 1, 11), w = randomUniform(N * K, -0.05f, 0.05f, 12);
  Tensor tx = eng().fromFloats({M, K}, x), tw = eng().fromFloats({N, K}, w);
  ASSERT_GT(tw.bytes(), eng().caps().maxStorageBufferRange > (1ull << 30) ? 0 : (128ull << 20));
  GuardedOutput y(eng(), {M, N});
  Recorder rec(eng());
  linear(rec, tx, tw, Tensor(), y.tensor());
  rec.run();
  expectClose(y.read(), linearRef(x, w, {}, 1, M, N, K, false, Activation::None), 1e-9, 1e-4, "big weight");
  y.expectAllWritten();
}

// Outputs beyond one storage binding are written in row chunks. The binding limit is
// lowered so the split is exercised at a small size, then once at the real limit.
TEST_F(EngineTest, LinearOutputSplitIntoChunks) {
  const int64_t M = 1000, N = 40, K = 8;
  auto x = randomUniform(M * K, -1, 1, 13), w = randomUniform(N * K, -1, 1, 14);
  Tensor tx = eng().fromFloats({M, K}, x), tw = eng().fromFloats({N, K}, w);
  GuardedOutput y(eng(), {M, N});
  ScopedBindingRange lowered(eng(), 256 * N * 4);  // 256 rows a chunk: 4 chunks
  Recorder rec(eng());
  linear(rec, tx, tw, Tensor(), y.tensor());
  EXPECT_EQ(rec.pending(), 4u);
  rec.run();
  lowered.restore();
  expectClose(y.read(), linearRef(x, w, {}, 1, M, N, K, false, Activation::None), 1e-10, 1e-4, "chunked");
  y.expectAllWritten();
}

TEST_F(EngineTest, LinearOutputAboveStorageRange) {
  const int64_t N = 16384, K = 4;
  const int64_t M = int64_t(eng().device().bindingRangeLimit() / (N * 4)) + 300;
  if (M * N * 4 > (int64_t(1) << 31)) GTEST_SKIP() << "storage range too large to exceed in a test";
  // SwiftShader: its largest allocation is its storage range (1 GiB), so no output exceeds it
  if (uint64_t(M * N * 4) > eng().caps().maxMemoryAllocationSize)
    GTEST_SKIP() << "the device allocates no buffer beyond its storage range";
  auto x = randomUniform(M * K, -1, 1, 15), w = randomUniform(N * K, -1, 1, 16);
  Tensor tx = eng().fromFloats({M, K}, x), tw = eng().fromFloats({N, K}, w);
  Tensor y = eng().tensor({M, N});
  Recorder rec(eng());
  linear(rec, tx, tw, Tensor(), y);
  EXPECT_GE(rec.pending(), 2u);
  rec.run();
  expectClose(eng().download(y), linearRef(x, w, {}, 1, M, N, K, false, Activation::None), 1e-10, 1e-4, "above range");
}

// ---- Quantized weights (engine/tensor.h DType::Q8 / Q4, shaders/quant.glsl), against float64
// of the dequantized weights: the kernel adds no error of its own beyond fp32 accumulation. On
// cooperative matrices (the plan's quantizedGemm() CoopMat: ctest's coopmat_linear) the kernel
// stages x and the dequantized weights as fp16, so the reference rounds both as it does.

void expectQuantizedLinear(Engine& engine, const std::vector<float>& w, int64_t M, int64_t N, int64_t K, int bits,
                           bool bias, Activation act, const std::string& what) {
  const auto x = randomUniform(M * K, -1, 1, 21);
  const auto b = bias ? randomUniform(N, -1, 1, 22) : std::vector<float>{};
  const QuantizedMatrix q = quantizeReference(w, N, K, bits);
  Tensor tx = engine.fromFloats({M, K}, x), tw = quantizedTensor(engine, q, N, K, bits);
  Tensor tb = bias ? engine.fromFloats({N}, b) : Tensor();
  GuardedOutput y(engine, {M, N});
  Recorder rec(engine);
  linear(rec, tx, tw, tb, y.tensor(), act);
  rec.run();
  const bool viaFp16 = engine.plan().quantizedGemm() == KernelFamily::CoopMat;
  const auto ref = viaFp16 ? linearRef(roundToHalf(x), roundToHalf(q.values), b, 1, M, N, K, false, act)
                           : linearRef(x, q.values, b, 1, M, N, K, false, act);
  double peak = 0;
  for (double v : ref) peak = std::max(peak, std::abs(v));
  expectClose(y.read(), ref, 1e-10 * std::max<int64_t>(1, K / 16), 1e-6 * std::max(1.0, peak), what);
  y.expectAllWritten();
}

// Odd M and N (rows past a register block), K of one and of several blocks, with and without
// bias and activation.
TEST_F(EngineTest, LinearQuantizedMatchesFloat64OfDequantized) {
  // (bias and activation as the other tests have them: each combination is one more kernel
  // variant to compile in each of the program's four runs)
  expectQuantizedLinear(eng(), randomUniform(61 * 96, -1, 1, 23), 7, 61, 96, 8, true, Activation::None, "q8 7x61x96");
  expectQuantizedLinear(eng(), randomUniform(61 * 96, -1, 1, 23), 7, 61, 96, 4, true, Activation::None, "q4 7x61x96");
  expectQuantizedLinear(eng(), randomUniform(37 * 32, -0.1f, 0.1f, 24), 33, 37, 32, 8, false, Activation::Gelu,
                        "q8 33x37x32 gelu, no bias");
}

// Stiff blocks: one outlier of 1e4 among values of 1e-2 (the block's small values round to 0
// codes), an all-zero block (scale 0), and blocks whose scale is float's smallest normal.
TEST_F(EngineTest, LinearQuantizedStiffBlocks) {
  const int64_t M = 5, N = 9, K = 128;
  const auto w = stiffQuantizedRows(N, K, 25);
  for (int bits : {8, 4}) {
    const QuantizedMatrix q = quantizeReference(w, N, K, bits);
    float tinyScale;
    std::memcpy(&tinyScale, q.rows.data() + K * bits / 8 + 2 * 4, 4);
    EXPECT_GE(tinyScale, std::numeric_limits<float>::min()) << "block 2's scale is a normal float";
    expectQuantizedLinear(eng(), w, M, N, K, bits, true, Activation::None, bits == 8 ? "q8 stiff" : "q4 stiff");
  }
}

// A quantized weight longer than the device's texel binding is read in row chunks, as f32
// weights are: 3646 rows of 18 words under the vulkan-1.2-min profile's 65536 texels (its
// device_profile run); on lavapipe's 2^27 texels, 40000 rows in one binding.
TEST_F(EngineTest, LinearQuantizedWeightInRowChunks) {
  const int64_t M = 3, K = 64;
  const uint64_t rowWords = rowBytes(DType::Q8, K) / 4;
  const int64_t N = int64_t(std::min<uint64_t>(eng().caps().maxTexelBufferElements / rowWords + 5, 40000));
  expectQuantizedLinear(eng(), randomUniform(N * K, -1, 1, 26), M, N, K, 8, true, Activation::None, "q8 row chunks");
}

TEST_F(EngineTest, LinearQuantizedRefusesBatchedAndPartialBlocks) {
  EXPECT_THROW(eng().tensor({4, 40}, DType::Q8), Error);  // rows must be whole blocks of 32
  Tensor x = eng().fromFloats({2, 3, 32}, randomUniform(2 * 3 * 32, -1, 1, 27));
  Tensor w = eng().tensor({2, 4, 32}, DType::Q8);
  GuardedOutput y(eng(), {2, 3, 4});
  Recorder rec(eng());
  EXPECT_THROW(linear(rec, x, w, Tensor(), y.tensor()), Error);
}

TEST_F(EngineTest, LinearRejectsMismatchedShapes) {
  Tensor x = eng().tensor({4, 8}), w = eng().tensor({6, 9}), y = eng().tensor({4, 6});
  Recorder rec(eng());
  EXPECT_THROW(linear(rec, x, w, Tensor(), y), Error);
  Tensor w2 = eng().tensor({6, 8}), yBad = eng().tensor({4, 5});
  EXPECT_THROW(linear(rec, x, w2, Tensor(), yBad), Error);
  EXPECT_EQ(rec.pending(), 0u);
}

}  // namespace
}  // namespace spar::test
