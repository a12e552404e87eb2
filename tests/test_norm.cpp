// LayerNorm and RMSNorm (shaders/norm.comp via engine/ops/norm.cpp) against float64 references.
#include <array>
#include <cstdlib>

#include "engine/ops/norm.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

// x: [rows, D]; weight/bias empty for none.
std::vector<double> layerNormRef(const std::vector<float>& x, int64_t rows, int64_t d, const std::vector<float>& w,
                                 const std::vector<float>& b, double eps) {
  std::vector<double> y(x.size());
  for (int64_t r = 0; r < rows; ++r) {
    const float* xr = &x[r * d];
    double mean = 0, var = 0;
    for (int64_t j = 0; j < d; ++j) mean += xr[j];
    mean /= double(d);
    for (int64_t j = 0; j < d; ++j) var += (xr[j] - mean) * (xr[j] - mean);
    var /= double(d);
    const double rstd = 1.0 / std::sqrt(var + eps);
    for (int64_t j = 0; j < d; ++j)
      y[r * d + j] = (xr[j] - mean) * rstd * (w.empty() ? 1.0 : double(w[j])) + (b.empty() ? 0.0 : double(b[j]));
  }
  return y;
}

// Normalizes heads of dh columns at xCol0 of x [rows, cx] into a copy of y0 [rows, cy] at yCol0.
std::vector<double> rmsNormRef(const std::vector<float>& x, int64_t rows, int64_t cx, int64_t xCol0,
                               const std::vector<float>& y0, int64_t cy, int64_t yCol0, int64_t heads,
                               const std::vector<float>& w, double eps) {
  std::vector<double> y = toDouble(y0);
  const int64_t dh = static_cast<int64_t>(w.size());
  for (int64_t r = 0; r < rows; ++r)
    for (int64_t h = 0; h < heads; ++h) {
      const float* xr = &x[r * cx + xCol0 + h * dh];
      double ms = 0;
      for (int64_t j = 0; j < dh; ++j) ms += double(xr[j]) * xr[j];
      const double rstd = 1.0 / std::sqrt(ms / double(dh) + eps);
      for (int64_t j = 0; j < dh; ++j) y[r * cy + yCol0 + h * dh + j] = xr[j] * rstd * w[j];
    }
  return y;
}

struct LayerNormCase {
  int64_t rows, d;
  bool weight, bias;
};
// Readable, stable CTest names (the default prints the struct's bytes, padding included).
void PrintTo(const LayerNormCase& c, std::ostream* os) {
  *os << c.rows << "x" << c.d << (c.weight ? "_weight" : "") << (c.bias ? "_bias" : "");
}

class LayerNormTest : public EngineTest, public ::testing::WithParamInterface<LayerNormCase> {};

TEST_P(LayerNormTest, MatchesFloat64Reference) {
  const auto c = GetParam();
  auto x = randomNormal(c.rows * c.d, 3.0f, 2.0f, 21);
  auto w = c.weight ? randomUniform(c.d, 0.5f, 1.5f, 22) : std::vector<float>{};
  auto b = c.bias ? randomUniform(c.d, -1, 1, 23) : std::vector<float>{};
  Tensor tx = eng().fromFloats({c.rows, c.d}, x);
  Tensor tw = c.weight ? eng().fromFloats({c.d}, w) : Tensor(), tb = c.bias ? eng().fromFloats({c.d}, b) : Tensor();
  GuardedOutput y(eng(), {c.rows, c.d});
  Recorder rec(eng());
  layerNorm(rec, tx, tw, tb, y.tensor());
  rec.run();
  expectClose(y.read(), layerNormRef(x, c.rows, c.d, w, b, 1e-5), 1e-9, 1e-5, "layernorm");
  y.expectAllWritten();
}

INSTANTIATE_TEST_SUITE_P(OddShapes, LayerNormTest,
                         ::testing::Values(LayerNormCase{7, 7, true, true}, LayerNormCase{61, 61, true, false},
                                           LayerNormCase{257, 257, false, false}, LayerNormCase{7, 257, false, true},
                                           LayerNormCase{257, 7, true, true}, LayerNormCase{1, 1, true, true},
                                           LayerNormCase{33, 768, true, true}, LayerNormCase{5, 3000, true, true}));

// Rows with mean 1e4 and variance 1e-6: in fp32 the values sit a few ulps (~1e-3) apart, so
// summing them unshifted loses everything; the kernel shifts by the row's first element.
TEST_F(EngineTest, LayerNormMean1e4Variance1e6) {
  for (int64_t d : {7, 61, 257, 1024}) {
    const int64_t rows = 37;
    auto x = randomNormal(rows * d, 1e4f, 1e-3f, 24 + uint32_t(d));
    auto w = randomUniform(d, 0.5f, 1.5f, 25), b = randomUniform(d, -1, 1, 26);
    Tensor tx = eng().fromFloats({rows, d}, x), tw = eng().fromFloats({d}, w), tb = eng().fromFloats({d}, b);
    GuardedOutput y(eng(), {rows, d});
    Recorder rec(eng());
    layerNorm(rec, tx, tw, tb, y.tensor(), 1e-12f);  // eps far below the variance
    rec.run();
    expectClose(y.read(), layerNormRef(x, rows, d, w, b, 1e-12), 1e-9, 1e-4,
                "mean 1e4 var 1e-6 D=" + std::to_string(d));
  }
}

// Constant rows normalize to exactly zero, so the output is exactly the bias (or zero).
TEST_F(EngineTest, LayerNormConstantRows) {
  for (int64_t d : {7, 61, 257, 64, 1024}) {
    const std::vector<float> levels = {0.0f, 1.0f, -3.7f, 1e4f, -1e30f, 1e-30f, 123456.789f};
    const int64_t rows = static_cast<int64_t>(levels.size());
    std::vector<float> x(rows * d);
    for (int64_t r = 0; r < rows; ++r) std::fill(x.begin() + r * d, x.begin() + (r + 1) * d, levels[r]);
    auto w = randomUniform(d, 0.5f, 1.5f, 27), b = randomUniform(d, -1, 1, 28);
    Tensor tx = eng().fromFloats({rows, d}, x), tw = eng().fromFloats({d}, w), tb = eng().fromFloats({d}, b);
    GuardedOutput y(eng(), {rows, d}), y0(eng(), {rows, d});
    Recorder rec(eng());
    layerNorm(rec, tx, tw, tb, y.tensor());
    layerNorm(rec, tx, tw, Tensor(), y0.tensor());
    rec.run();
    auto out = y.read(), out0 = y0.read();
    for (int64_t r = 0; r < rows; ++r)
      for (int64_t j = 0; j < d; ++j) {
        ASSERT_EQ(out[r * d + j], b[j]) << "row " << r << " (" << levels[r] << ") column " << j << " D=" << d;
        ASSERT_EQ(out0[r * d + j], 0.0f) << "row " << r << " column " << j << " D=" << d;
      }
  }
}

TEST_F(EngineTest, LayerNormInPlace) {
  for (int64_t d : {257, 256}) {
    const int64_t rows = 61;
    auto x = randomNormal(rows * d, -2.0f, 5.0f, 29);
    auto w = randomUniform(d, 0.5f, 1.5f, 30), b = randomUniform(d, -1, 1, 31);
    Tensor tx = eng().fromFloats({rows, d}, x), tw = eng().fromFloats({d}, w), tb = eng().fromFloats({d}, b);
    Recorder rec(eng());
    layerNorm(rec, tx, tw, tb, tx, 1e-6f);
    rec.run();
    expectClose(eng().download(tx), layerNormRef(x, rows, d, w, b, 1e-6), 1e-9, 1e-5,
                "in place D=" + std::to_string(d));
  }
}

// Leading dimensions are rows; the row split keeps every binding under the range limit.
TEST_F(EngineTest, LayerNormSplitIntoChunks) {
  const int64_t rows = 1000, d = 40;
  auto x = randomNormal(rows * d, 1.0f, 3.0f, 32);
  auto w = randomUniform(d, 0.5f, 1.5f, 33), b = randomUniform(d, -1, 1, 34);
  Tensor tx = eng().fromFloats({10, 100, d}, x), tw = eng().fromFloats({d}, w), tb = eng().fromFloats({d}, b);
  GuardedOutput y(eng(), {10, 100, d});
  ScopedBindingRange lowered(eng(), 256 * d * 4);  // 256 rows a chunk: 4 chunks
  Recorder rec(eng());
  layerNorm(rec, tx, tw, tb, y.tensor());
  EXPECT_EQ(rec.pending(), 4u);
  rec.run();
  lowered.restore();
  expectClose(y.read(), layerNormRef(x, rows, d, w, b, 1e-5), 1e-9, 1e-5, "chunked");
  y.expectAllWritten();
}

TEST_F(EngineTest, LayerNormRejectsBadShapes) {
  Tensor x = eng().tensor({4, 8}), y = eng().tensor({4, 8}), w = eng().tensor({7}), y2 = eng().tensor({8, 4});
  Tensor xi = eng().tensor({4, 8}, DType::I32);
  Recorder rec(eng());
  EXPECT_THROW(layerNorm(rec, x, w, Tensor(), y), Error);
  EXPECT_THROW(layerNorm(rec, x, Tensor(), w, y), Error);
  EXPECT_THROW(layerNorm(rec, x, Tensor(), Tensor(), y2), Error);
  EXPECT_THROW(layerNorm(rec, xi, Tensor(), Tensor(), y), Error);
  Tensor big = eng().tensor({40});
  EXPECT_THROW(layerNorm(rec, big.view(0, {4, 8}), Tensor(), Tensor(), big.view(4, {4, 8})), Error);  // overlap
  EXPECT_EQ(rec.pending(), 0u);
}

struct RmsNormCase {
  int64_t rows, heads, dh;
};
void PrintTo(const RmsNormCase& c, std::ostream* os) { *os << c.rows << "x" << c.heads << "x" << c.dh; }

class RmsNormTest : public EngineTest, public ::testing::WithParamInterface<RmsNormCase> {};

// Out of place on [rows, heads * dh] with a per-head weight.
TEST_P(RmsNormTest, MatchesFloat64Reference) {
  const auto c = GetParam();
  const int64_t d = c.heads * c.dh;
  auto x = randomNormal(c.rows * d, 0.5f, 2.0f, 35);
  auto w = randomUniform(c.dh, 0.5f, 1.5f, 36);
  Tensor tx = eng().fromFloats({c.rows, d}, x), tw = eng().fromFloats({c.dh}, w);
  GuardedOutput y(eng(), {c.rows, d});
  Recorder rec(eng());
  rmsNorm(rec, tx, tw, y.tensor(), 1e-6f);
  rec.run();
  expectClose(y.read(), rmsNormRef(x, c.rows, d, 0, std::vector<float>(x.size()), d, 0, c.heads, w, 1e-6), 1e-9, 1e-5,
              "rmsnorm");
  y.expectAllWritten();
}

INSTANTIATE_TEST_SUITE_P(OddShapes, RmsNormTest,
                         ::testing::Values(RmsNormCase{7, 1, 7}, RmsNormCase{61, 3, 61}, RmsNormCase{257, 2, 257},
                                           RmsNormCase{61, 12, 64}, RmsNormCase{257, 5, 16}, RmsNormCase{3, 1, 3072}));

// The float64 reference of q_norm on the q part and k_norm on the k part of qkv [T, 3D] (H heads
// of dh each), and the check that the v part came out bit-identical.
static std::vector<double> qkNormRef(const std::vector<float>& qkv, int64_t T, int64_t H, int64_t dh,
                                     const std::vector<float>& wq, const std::vector<float>& wk) {
  const int64_t D = H * dh;
  const auto afterQ = rmsNormRef(qkv, T, 3 * D, 0, qkv, 3 * D, 0, H, wq, 1e-6);
  return rmsNormRef(qkv, T, 3 * D, D, std::vector<float>(afterQ.begin(), afterQ.end()), 3 * D, D, H, wk, 1e-6);
}

static void expectVUntouched(const std::vector<float>& out, const std::vector<float>& qkv, int64_t T, int64_t D) {
  for (int64_t r = 0; r < T; ++r)
    for (int64_t j = 2 * D; j < 3 * D; ++j) ASSERT_EQ(out[r * 3 * D + j], qkv[r * 3 * D + j]) << "v changed";
}

// In place on the q part, then the k part, of a fused qkv tensor [T, 3D]; v stays untouched.
TEST_F(EngineTest, RmsNormHeadsInPlaceOnFusedQkv) {
  for (int64_t dh : {16, 64}) {
    const int64_t T = 61, H = 3, D = H * dh;
    auto qkv = randomNormal(T * 3 * D, 0.0f, 3.0f, 37 + uint32_t(dh));
    auto wq = randomUniform(dh, 0.5f, 1.5f, 38), wk = randomUniform(dh, 0.5f, 1.5f, 39);
    Tensor t = eng().fromFloats({T, 3 * D}, qkv), twq = eng().fromFloats({dh}, wq), twk = eng().fromFloats({dh}, wk);
    Recorder rec(eng());
    rmsNormHeads(rec, t, 0, t, 0, H, twq);
    rmsNormHeads(rec, t, D, t, D, H, twk);
    rec.run();
    auto out = eng().download(t);
    expectClose(out, qkNormRef(qkv, T, H, dh, wq, wk), 1e-9, 1e-5, "qkv in place dh=" + std::to_string(dh));
    expectVUntouched(out, qkv, T, D);
  }
}

// The q and the k heads in one dispatch (the transformer block's qk-norm): 2H heads at column
// 0 with a [2, dh] weight, q_norm for the first H and k_norm for the next; the same values as
// the two calls with a weight each, v untouched, and a weight whose rows do not divide the heads
// (or that has none) refused.
TEST_F(EngineTest, RmsNormHeadsWithAWeightRowPerGroup) {
  for (int64_t dh : {12, 64}) {
    const int64_t T = 61, H = 3, D = H * dh;
    auto qkv = randomNormal(T * 3 * D, 1.0f, 2.0f, 47);
    auto wq = randomUniform(dh, 0.5f, 1.5f, 48), wk = randomUniform(dh, 0.5f, 1.5f, 49);
    std::vector<float> wqk(wq);
    wqk.insert(wqk.end(), wk.begin(), wk.end());
    Tensor t = eng().fromFloats({T, 3 * D}, qkv), tw = eng().fromFloats({2, dh}, wqk);
    Recorder rec(eng());
    rmsNormHeads(rec, t, 0, t, 0, 2 * H, tw);
    rec.run();
    EXPECT_EQ(rec.lastRunTotal().dispatches, 1u);
    auto out = eng().download(t);
    expectClose(out, qkNormRef(qkv, T, H, dh, wq, wk), 1e-9, 1e-5, "q and k heads at once dh=" + std::to_string(dh));
    expectVUntouched(out, qkv, T, D);
    EXPECT_THROW(rmsNormHeads(rec, t, 0, t, 0, 2 * H + 1, tw), Error);
    EXPECT_THROW(rmsNormHeads(rec, t, 0, t, 0, 2 * H, eng().tensor({0, dh})), Error);  // no rows: no crash
  }
}

// Out of place from the k part of qkv [T, 3D] into a tensor [T, D].
TEST_F(EngineTest, RmsNormHeadsFromColumnsIntoTensor) {
  const int64_t T = 257, H = 5, dh = 32, D = H * dh;
  auto qkv = randomNormal(T * 3 * D, 1.0f, 2.0f, 40);
  auto w = randomUniform(dh, 0.5f, 1.5f, 41);
  Tensor t = eng().fromFloats({T, 3 * D}, qkv), tw = eng().fromFloats({dh}, w);
  GuardedOutput k(eng(), {T, D});
  Recorder rec(eng());
  rmsNormHeads(rec, t, D, k.tensor(), 0, H, tw, 1e-5f);
  rec.run();
  expectClose(k.read(), rmsNormRef(qkv, T, 3 * D, D, std::vector<float>(T * D), D, 0, H, w, 1e-5), 1e-9, 1e-5,
              "k heads");
  k.expectAllWritten();
}

// A head of zeros normalizes to zeros, also with eps = 0 (no 0/0).
TEST_F(EngineTest, RmsNormAllZeroHead) {
  for (int64_t dh : {7, 64}) {
    const int64_t rows = 7, H = 4, D = H * dh;
    auto x = randomNormal(rows * D, 0.0f, 1.0f, 42);
    for (int64_t r = 0; r < rows; ++r)
      for (int64_t j = 0; j < dh; ++j) x[r * D + (r % H) * dh + j] = 0.0f;  // one zero head per row
    auto w = randomUniform(dh, 0.5f, 1.5f, 43);
    Tensor tx = eng().fromFloats({rows, D}, x), tw = eng().fromFloats({dh}, w);
    GuardedOutput y(eng(), {rows, D}), y0(eng(), {rows, D});
    Recorder rec(eng());
    rmsNorm(rec, tx, tw, y.tensor(), 1e-6f);
    rmsNorm(rec, tx, tw, y0.tensor(), 0.0f);
    rec.run();
    auto ref = rmsNormRef(x, rows, D, 0, std::vector<float>(x.size()), D, 0, H, w, 1e-6);
    auto out = y.read(), out0 = y0.read();
    expectClose(out, ref, 1e-9, 1e-5, "zero heads dh=" + std::to_string(dh));
    for (int64_t r = 0; r < rows; ++r)
      for (int64_t j = 0; j < dh; ++j) {
        ASSERT_EQ(out[r * D + (r % H) * dh + j], 0.0f);
        ASSERT_EQ(out0[r * D + (r % H) * dh + j], 0.0f) << "eps = 0";
      }
    y0.expectAllWritten();  // no NaN anywhere
  }
}

TEST_F(EngineTest, RmsNormRejectsBadShapes) {
  Tensor x = eng().tensor({4, 24}), y = eng().tensor({4, 24}), w5 = eng().tensor({5}), w8 = eng().tensor({8});
  Recorder rec(eng());
  EXPECT_THROW(rmsNorm(rec, x, w5, y), Error);                                    // 24 is not a multiple of 5
  EXPECT_THROW(rmsNormHeads(rec, x, 16, y, 0, 2, w8), Error);                     // 2 heads at 16 pass column 24
  EXPECT_THROW(rmsNormHeads(rec, x, 0, x, 8, 1, w8), Error);                      // in place at another column
  EXPECT_THROW(rmsNormHeads(rec, x, 0, eng().tensor({5, 24}), 0, 1, w8), Error);  // rows differ
  EXPECT_EQ(rec.pending(), 0u);
}

// The workgroup shapes other devices get (lines split over 16-64 invocations, several lines
// a workgroup) give the same results as lavapipe's.
TEST_F(EngineTest, NormWorkgroupShapesAgree) {
  // {1, LX, 1}: one split line a workgroup, the subgroup-reduction variants where the plan has
  // them (the GPU family: SPAR_KERNELS=gpu).
  const KernelTuning saved = eng().options().tuning;
  for (const std::array<int, 3> group :
       {std::array{1, 16, 4}, {1, 64, 2}, {1, 8, 3}, {0, 16, 2}, {0, 8, 1}, {1, 64, 1}, {1, 8, 1}}) {
    KernelTuning tuning = saved;
    tuning.lineGroup = group;
    eng().setTuning(tuning);
    const std::string shape = std::to_string(group[0]) + "," + std::to_string(group[1]) + "," + std::to_string(group[2]);
    for (int64_t d : {7, 61, 256, 257}) {
      const int64_t rows = 29;
      auto x = randomNormal(rows * d, 3.0f, 2.0f, 44);
      auto w = randomUniform(d, 0.5f, 1.5f, 45), b = randomUniform(d, -1, 1, 46);
      Tensor tx = eng().fromFloats({rows, d}, x), tw = eng().fromFloats({d}, w), tb = eng().fromFloats({d}, b);
      GuardedOutput ln(eng(), {rows, d}), rms(eng(), {rows, d});
      Recorder rec(eng());
      layerNorm(rec, tx, tw, tb, ln.tensor());
      rmsNorm(rec, tx, tw, rms.tensor());
      rec.run();
      const std::string what = shape + " D=" + std::to_string(d);
      expectClose(ln.read(), layerNormRef(x, rows, d, w, b, 1e-5), 1e-9, 1e-5, "layernorm " + what);
      expectClose(rms.read(), rmsNormRef(x, rows, d, 0, std::vector<float>(x.size()), d, 0, 1, w, 1e-6), 1e-9, 1e-5,
                  "rmsnorm " + what);
      ln.expectAllWritten();
      rms.expectAllWritten();
    }
  }
  eng().setTuning(saved);
}

}  // namespace
}  // namespace spar::test
