// Fused attention (shaders/attention.comp via engine/ops/attention.cpp) against float64.
#include "engine/ops/attention.h"

#include "tests/test_support.h"

namespace spar::test {
namespace {

struct AttentionCase {
  int64_t B, N;
  int heads, dh;
  bool causal;
};

class AttentionTest : public EngineTest, public ::testing::WithParamInterface<AttentionCase> {};

// Self-attention reading q, k, v straight out of one fused qkv tensor [B, N, 3D].
void expectFusedQkvMatches(Engine& engine, const AttentionCase& c, const std::string& what) {
  const int64_t D = int64_t(c.heads) * c.dh;
  auto qkv = randomNormal(c.B * c.N * 3 * D, 0, 1, 21);
  Tensor t = engine.fromFloats({c.B, c.N, 3 * D}, qkv);
  GuardedOutput out(engine, {c.B, c.N, D});
  Recorder rec(engine);
  attention(rec, {t, 0}, {t, D}, {t, 2 * D}, {out.tensor(), 0}, c.heads, c.dh, c.causal);
  rec.run();
  auto ref = attentionRef(qkv, 3 * D, 0, qkv, 3 * D, D, qkv, 3 * D, 2 * D, c.B, c.N, c.N, c.heads, c.dh, c.causal,
                          1.0 / std::sqrt(double(c.dh)));
  expectClose(out.read(), ref, 1e-9, 1e-4, what);
  out.expectAllWritten();
}

TEST_P(AttentionTest, FusedQkvMatchesFloat64) { expectFusedQkvMatches(eng(), GetParam(), "attention"); }

INSTANTIATE_TEST_SUITE_P(Shapes, AttentionTest,
                         ::testing::Values(AttentionCase{1, 61, 2, 32, false}, AttentionCase{2, 7, 3, 16, false},
                                           AttentionCase{1, 257, 2, 64, false}, AttentionCase{2, 61, 2, 32, true},
                                           AttentionCase{1, 130, 1, 64, true}, AttentionCase{1, 1, 1, 16, false}));

// The q / k preparation (QkPrep: the heads' RMS norm, then RoPE) against float64: the heads
// normed and rotated on the host in double, then attended. In the kernel (attention.comp,
// attention_tiled.comp, SwiftShader's attention_lanes.comp) or, where it cannot (RoPE channels
// that do not pair up: heads not a multiple of 8 wide, an odd number of channels a lane), by
// rmsNormHeads and rope() first: norm only, RoPE only after a
// prefix of unrotated tokens, both, causal, batches, odd token counts, a head of 1e3-sized
// values and an all-zero k head (eps 0 there: it stays 0, no NaN).
struct PrepCase {
  int64_t B, N;
  int heads, dh;
  bool causal, norm, rope;
  int64_t prefix;
  float eps;
};

void expectPreparedMatches(Engine& engine, const PrepCase& c, const std::string& what) {
  const int64_t D = int64_t(c.heads) * c.dh, C = 3 * D;
  std::vector<float> qkv = randomNormal(c.B * c.N * C, 0, 1, 31);
  for (int64_t i = 0; i < c.dh; ++i) qkv[size_t(C + i)] *= 1e3f;              // token 1's first q head: large
  for (int64_t i = 0; i < c.dh; ++i) qkv[size_t(2 * C + D + i)] = 0.0f;       // token 2's first k head: zero
  const std::vector<float> w = randomUniform(2 * c.dh, 0.5f, 1.5f, 32), angles = randomUniform((c.N - c.prefix) * c.dh, -3, 3, 33);
  std::vector<float> sines, cosines;
  for (float a : angles) sines.push_back(std::sin(a)), cosines.push_back(std::cos(a));
  const std::vector<double> prepared = prepareQkRef(qkv, c.B, c.N, c.heads, c.dh, c.norm ? w : std::vector<float>{}, c.eps,
                                                    c.rope ? sines : std::vector<float>{},
                                                    c.rope ? cosines : std::vector<float>{}, c.prefix);
  const std::vector<float> preparedF(prepared.begin(), prepared.end());
  const auto ref = attentionRef(preparedF, C, 0, preparedF, C, D, preparedF, C, 2 * D, c.B, c.N, c.N, c.heads, c.dh,
                                c.causal, 1.0 / std::sqrt(double(c.dh)));
  const Tensor t = engine.fromFloats({c.B, c.N, C}, qkv);
  QkPrep prep;
  if (c.norm) prep.normWeight = engine.fromFloats({2, c.dh}, w), prep.normEps = c.eps;
  if (c.rope) {
    prep.ropeSin = engine.fromFloats({c.N - c.prefix, c.dh}, sines);
    prep.ropeCos = engine.fromFloats({c.N - c.prefix, c.dh}, cosines);
    prep.ropePrefix = c.prefix;
  }
  GuardedOutput out(engine, {c.B, c.N, D});
  Recorder rec(engine);
  attention(rec, {t, 0}, {t, D}, {t, 2 * D}, {out.tensor(), 0}, c.heads, c.dh, c.causal, 0.0f, false, prep);
  rec.run();
  expectClose(out.read(), ref, 1e-9, 1e-4, what);
  out.expectAllWritten();
  if (preparesInKernel(engine, c.dh, prep)) EXPECT_EQ(rec.lastRunTotal().dispatches, 1u) << what << ": the preparation ran apart";
}

TEST_F(EngineTest, AttentionPreparesQAndKAsTheOpsWould) {
  for (const PrepCase c : {PrepCase{2, 61, 2, 32, false, true, false, 0, 1e-6f}, PrepCase{1, 37, 1, 64, true, true, false, 0, 0.0f},
                           PrepCase{2, 37, 2, 64, false, false, true, 5, 1e-6f}, PrepCase{1, 9, 3, 16, true, true, true, 1, 1e-5f},
                           PrepCase{1, 13, 2, 12, false, true, true, 3, 1e-6f}}) {
    const std::string what = std::string(c.norm ? "norm " : "") + (c.rope ? "rope " : "") + "N " + std::to_string(c.N) +
                             ", dh " + std::to_string(c.dh) + (c.causal ? ", causal" : "");
    expectPreparedMatches(eng(), c, what);
  }
  withLanesKernelsForced(eng(), [&](const std::string& inputs) {
    for (const PrepCase c : {PrepCase{2, 9, 2, 16, false, true, true, 2, 1e-6f}, PrepCase{1, 37, 2, 32, true, true, true, 3, 1e-6f},
                             PrepCase{1, 11, 1, 32, false, true, false, 0, 1e-6f}, PrepCase{2, 9, 1, 24, false, true, true, 1, 1e-6f}})
      expectPreparedMatches(eng(), c, "lanes, " + inputs + " inputs, dh " + std::to_string(c.dh) + (c.rope ? ", rope" : ""));
  });
  // q and k not in one fused tensor, or tables of the wrong size: refused
  const Tensor q = eng().tensor({1, 8, 16}), qkv = eng().tensor({1, 8, 48}), out = eng().tensor({1, 8, 16});
  QkPrep norm;
  norm.normWeight = eng().tensor({2, 16});
  Recorder rec(eng());
  EXPECT_THROW(attention(rec, {q, 0}, {q, 0}, {q, 0}, {out, 0}, 1, 16, false, 0.0f, false, norm), Error);
  QkPrep rope;
  rope.ropeSin = rope.ropeCos = eng().tensor({8, 16});
  rope.ropePrefix = 1;  // 7 rows wanted
  EXPECT_THROW(attention(rec, {qkv, 0}, {qkv, 16}, {qkv, 32}, {out, 0}, 1, 16, false, 0.0f, false, rope), Error);
}

// Cross attention: separate q, k, v tensors, fewer queries than keys, k's heads at column 4,
// output written into a column slice of a wider tensor.
void expectCrossAttentionMatches(Engine& engine, const std::string& what) {
  const int64_t B = 2, Nq = 19, Nk = 45;
  const int heads = 2, dh = 24;
  auto q = randomNormal(B * Nq * 48, 0, 1, 22), k = randomNormal(B * Nk * 52, 0, 1, 23), v = randomNormal(B * Nk * 48, 0, 1, 24);
  Tensor tq = engine.fromFloats({B, Nq, 48}, q), tk = engine.fromFloats({B, Nk, 52}, k), tv = engine.fromFloats({B, Nk, 48}, v);
  Tensor wide = engine.tensor({B, Nq, 60});
  std::vector<float> fill(B * Nq * 60, 7.0f);
  engine.upload(wide, fill);
  Recorder rec(engine);
  attention(rec, {tq, 0}, {tk, 4}, {tv, 0}, {wide, 10}, heads, dh, false, 0.3f);
  rec.run();
  auto ref = attentionRef(q, 48, 0, k, 52, 4, v, 48, 0, B, Nq, Nk, heads, dh, false, 0.3);
  auto got = engine.download(wide);
  std::vector<float> slice;
  for (int64_t r = 0; r < B * Nq; ++r) {
    for (int64_t c = 0; c < 60; ++c) {
      if (c >= 10 && c < 10 + heads * dh) slice.push_back(got[r * 60 + c]);
      else ASSERT_EQ(got[r * 60 + c], 7.0f) << what << ": wrote outside the head columns";
    }
  }
  expectClose(slice, ref, 1e-9, 1e-4, what);
}

TEST_F(EngineTest, AttentionSeparateTensorsAndOutputSlice) { expectCrossAttentionMatches(eng(), "cross"); }

// Logits of +-1e4: the softmax is one-hot; the online max must keep it finite and exact.
void expectLogitsOfTenThousandMatch(Engine& engine, const std::string& what) {
  const int64_t N = 37;
  const int heads = 1, dh = 16;
  auto q = randomNormal(N * dh, 0, 1, 25), k = randomNormal(N * dh, 0, 1, 26), v = randomNormal(N * dh, 0, 1, 27);
  for (auto& x : q) x = x > 0 ? 25.0f : -25.0f;  // |q.k| ~ 1e4 with scale 1
  for (auto& x : k) x *= 25.0f;
  Tensor tq = engine.fromFloats({N, dh}, q), tk = engine.fromFloats({N, dh}, k), tv = engine.fromFloats({N, dh}, v);
  GuardedOutput out(engine, {N, dh});
  Recorder rec(engine);
  attention(rec, {tq, 0}, {tk, 0}, {tv, 0}, {out.tensor(), 0}, heads, dh, false, 1.0f);
  rec.run();
  auto ref = attentionRef(q, dh, 0, k, dh, 0, v, dh, 0, 1, N, N, heads, dh, false, 1.0);
  expectClose(out.read(), ref, 1e-9, 1e-4, what);
  out.expectAllWritten();
}

TEST_F(EngineTest, AttentionLogitsOfTenThousand) { expectLogitsOfTenThousandMatch(eng(), "logits 1e4"); }

// SwiftShader's attention (attention_lanes.comp: a subgroup's lanes split the head dimension,
// its constants written into the module) forced on this device, through texel and storage
// inputs: the cases above, plus query and key counts that are no multiple of a workgroup's 4
// queries or a block's 4 keys, causal masks, batches and 64-wide heads. Every case must have
// run that kernel (on lavapipe's 8 lanes and SwiftShader's 4 these heads divide evenly).
TEST_F(EngineTest, AttentionLanesSplitDimMatchesFloat64) {
  withLanesKernelsForced(eng(), [&](const std::string& inputs) {
    const std::string tag = "lanes, " + inputs + " inputs, ";
    for (const AttentionCase c : {AttentionCase{2, 61, 2, 32, false}, AttentionCase{1, 37, 1, 64, true},
                                  AttentionCase{2, 9, 3, 16, true}, AttentionCase{1, 1, 1, 16, false}})
      expectFusedQkvMatches(eng(), c, tag + "N " + std::to_string(c.N) + ", dh " + std::to_string(c.dh));
    expectCrossAttentionMatches(eng(), tag + "cross");
    expectLogitsOfTenThousandMatch(eng(), tag + "logits 1e4");
  });
  size_t lanesPipelines = 0;
  for (const Pipeline* p : eng().pipelines().pipelines()) lanesPipelines += p->name.rfind("attention_lanes", 0) == 0;
  const DeviceCaps& caps = eng().caps();
  if (caps.subgroupArithmetic && caps.fullSubgroups && 16 % caps.subgroupSize == 0)
    EXPECT_GT(lanesPipelines, 0u) << "no case ran attention_lanes.comp";
}

// attention_flash.comp (the GPU family's attention with tiles of scores) forced with both ways of
// combining a group's rows: 8 lanes, within a subgroup (shuffles, SG_ROWS), through texel inputs,
// and 16 lanes (through shared memory where the subgroup is narrower, as on lavapipe's 8),
// through storage inputs: odd token counts, causal masks, batches, heads of 16 to 96 (lanes
// without an output texel, two texels a lane, a key block shrunk to fit), cross attention into a
// column slice, logits of 1e4 and q / k preparation. Every case must have run that kernel.
// (256 invocations a workgroup ran as right, but llvmpipe takes 8-13 s to compile each.)
TEST_F(EngineTest, AttentionFlashMatchesFloat64) {
  const KernelTuning saved = eng().options().tuning;
  const DeviceCaps& caps = eng().caps();
  KernelTuning t = saved;
  t.kernels = "gpu";
  t.inputs = "texel";
  t.gpuAttentionTiles = std::array<int, 3>{32, 32, int(std::min<uint32_t>(8, caps.subgroupSize))};
  eng().setTuning(t);
  for (const AttentionCase c : {AttentionCase{2, 61, 2, 32, false}, AttentionCase{1, 70, 1, 64, true},
                                AttentionCase{1, 37, 1, 96, false}})
    expectFusedQkvMatches(eng(), c, "flash, 8 lanes, N " + std::to_string(c.N) + ", dh " + std::to_string(c.dh));
  expectLogitsOfTenThousandMatch(eng(), "flash, 8 lanes, logits 1e4");
  expectPreparedMatches(eng(), PrepCase{2, 37, 2, 64, true, true, true, 5, 1e-6f}, "flash, 8 lanes, prepared");
  t.inputs = "storage";
  t.gpuAttentionTiles = std::array<int, 3>{32, 32, 16};
  eng().setTuning(t);
  for (const AttentionCase c : {AttentionCase{2, 9, 3, 16, true}, AttentionCase{1, 1, 1, 16, false}})
    expectFusedQkvMatches(eng(), c, "flash, 16 lanes, N " + std::to_string(c.N) + ", dh " + std::to_string(c.dh));
  expectCrossAttentionMatches(eng(), "flash, 16 lanes, cross");
  expectPreparedMatches(eng(), PrepCase{1, 9, 3, 16, false, true, false, 0, 0.0f}, "flash, 16 lanes, prepared");
  // 64 queries of 64-wide heads at 16 lanes: where even 16 keys a block do not fit the shared
  // memory (lavapipe's 32 KiB), the lanes halve until they do.
  t.gpuAttentionTiles = std::array<int, 3>{64, 32, 16};
  eng().setTuning(t);
  expectFusedQkvMatches(eng(), AttentionCase{1, 70, 1, 64, true}, "flash, 64 queries, lanes to fit");
  eng().setTuning(saved);
  if (attentionFlashSharedBytes(64, 16, 16, 64) > caps.maxSharedMemory) {
    bool halved = false;
    for (const Pipeline* p : eng().pipelines().pipelines())
      halved |= p->name.rfind("attention_flash", 0) == 0 &&
                (p->name.find(",64,8>") != std::string::npos || p->name.find(",64,4>") != std::string::npos);
    EXPECT_TRUE(halved) << "no flash kernel with its lanes halved to fit";
  }
  size_t flash = 0, flashSg = 0;
  for (const Pipeline* p : eng().pipelines().pipelines()) {
    flash += p->name.rfind("attention_flash", 0) == 0;
    flashSg += p->name.rfind("attention_flash_sg", 0) == 0;
  }
  EXPECT_GE(flash, 10u) << "a case ran another kernel";
  if (caps.subgroupShuffle && caps.fullSubgroups && caps.subgroupSize >= 16) EXPECT_EQ(flashSg, flash);
  else if (caps.subgroupShuffle && caps.fullSubgroups && caps.subgroupSize >= 2) EXPECT_GT(flash, flashSg) << "no case combined rows through shared memory";
}

// One key dominates every row (its logit exceeds the rest by ~60): output ~= that value row.
TEST_F(EngineTest, AttentionOneKeyDominates) {
  const int64_t N = 50;
  const int dh = 16;
  auto q = randomNormal(N * dh, 0, 0.1f, 28), k = randomNormal(N * dh, 0, 0.1f, 29), v = randomNormal(N * dh, 0, 1, 30);
  for (int64_t i = 0; i < N; ++i) q[i * dh] = 10.0f;
  k[33 * dh] = 50.0f;  // key 33: logit 500 * scale vs ~0 for the rest
  Tensor tq = eng().fromFloats({N, dh}, q), tk = eng().fromFloats({N, dh}, k), tv = eng().fromFloats({N, dh}, v);
  GuardedOutput out(eng(), {N, dh});
  Recorder rec(eng());
  attention(rec, {tq, 0}, {tk, 0}, {tv, 0}, {out.tensor(), 0}, 1, dh, false);
  rec.run();
  auto ref = attentionRef(q, dh, 0, k, dh, 0, v, dh, 0, 1, N, N, 1, dh, false, 1.0 / std::sqrt(16.0));
  expectClose(out.read(), ref, 1e-9, 1e-5, "dominant key");
}

// fp16 q/k/v with fp32 accumulation: exact up to fp32 error on the fp16-rounded inputs (up to
// fp16 products on cooperative matrices).
TEST_F(EngineTest, AttentionFp16Storage) {
  if (!eng().caps().supportsFp16Storage()) GTEST_SKIP() << "device without fp16 storage";
  const int64_t N = 77;
  const int heads = 2, dh = 32, D = heads * dh;
  auto qkv = randomNormal(N * 3 * D, 0, 1, 31);
  Tensor t = eng().fromFloats({N, 3 * D}, qkv, DType::F16);
  GuardedOutput out(eng(), {N, D}, DType::F16);
  GuardedOutput out32(eng(), {N, D}, DType::F32);
  Recorder rec(eng());
  attention(rec, {t, 0}, {t, D}, {t, 2 * D}, {out.tensor(), 0}, heads, dh, false);
  attention(rec, {t, 0}, {t, D}, {t, 2 * D}, {out32.tensor(), 0}, heads, dh, false);
  rec.run();
  auto rounded = roundToHalf(qkv);
  auto refRounded = attentionRef(rounded, 3 * D, 0, rounded, 3 * D, D, rounded, 3 * D, 2 * D, 1, N, N, heads, dh, false,
                                 1.0 / std::sqrt(double(dh)));
  auto refExact = attentionRef(qkv, 3 * D, 0, qkv, 3 * D, D, qkv, 3 * D, 2 * D, 1, N, N, heads, dh, false,
                               1.0 / std::sqrt(double(dh)));
  // Where the plan sends fp16 inputs to cooperative matrices (plan().attentionF16), the products
  // are fp16 (probabilities rounded too): tests/coopmat/test_coopmat.cpp's bound for that kernel.
  const bool coopMat = eng().plan().attentionF16 == KernelFamily::CoopMat;
  expectClose(out32.read(), refRounded, coopMat ? 1e-6 : 1e-9, coopMat ? 2e-2 : 1e-4, "f16 in, f32 out vs rounded");
  expectClose(out.read(), refExact, 1e-5, 1e-2, "f16 in, f16 out vs fp32");
  out.expectAllWritten();
}

// fp16 output of values above 65504 saturates instead of overflowing to inf.
TEST_F(EngineTest, AttentionFp16OutputOverflowSaturates) {
  if (!eng().caps().supportsFp16Storage()) GTEST_SKIP() << "device without fp16 storage";
  const int64_t N = 9;
  const int dh = 16;
  std::vector<float> q(N * dh, 0.0f), k(N * dh, 0.0f), v(N * dh);
  for (int64_t i = 0; i < N * dh; ++i) v[i] = (i % 2 ? -1.0f : 1.0f) * 1e5f;  // every output row: +-1e5
  Tensor tq = eng().fromFloats({N, dh}, q), tk = eng().fromFloats({N, dh}, k), tv = eng().fromFloats({N, dh}, v);
  GuardedOutput out(eng(), {N, dh}, DType::F16);
  Recorder rec(eng());
  attention(rec, {tq, 0}, {tk, 0}, {tv, 0}, {out.tensor(), 0}, 1, dh, false);
  rec.run();
  auto got = out.read();
  for (int64_t i = 0; i < N * dh; ++i) EXPECT_EQ(got[i], (i % 2 ? -1.0f : 1.0f) * 65504.0f) << i;
}

TEST_F(EngineTest, AttentionRejectsBadLayouts) {
  Tensor t = eng().tensor({10, 64});
  Recorder rec(eng());
  EXPECT_THROW(attention(rec, {t, 0}, {t, 0}, {t, 0}, {t, 0}, 2, 6), Error);     // head dim not a multiple of 4
  EXPECT_THROW(attention(rec, {t, 0}, {t, 40}, {t, 0}, {t, 0}, 2, 16), Error);   // heads run past the row
  Tensor k = eng().tensor({12, 64});
  EXPECT_THROW(attention(rec, {t, 0}, {k, 0}, {k, 0}, {t, 0}, 2, 16, true), Error);  // causal needs Nq == Nk
  EXPECT_EQ(rec.pending(), 0u);
}

}  // namespace
}  // namespace spar::test
