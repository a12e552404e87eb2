// Softmax, L2 normalization and argmax along an axis (shaders/reduce_channels.comp via
// engine/ops/reduce_channels.cpp) against float64 references.
#include <array>
#include <cstdlib>
#include <limits>

#include "engine/ops/reduce_channels.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

// x viewed as [outer, C, inner]; f(line values) -> line results, written back in place.
template <class F>
std::vector<double> perLine(const std::vector<float>& x, int64_t outer, int64_t C, int64_t inner, F f) {
  std::vector<double> y(x.size());
  std::vector<double> line(C);
  for (int64_t o = 0; o < outer; ++o)
    for (int64_t i = 0; i < inner; ++i) {
      for (int64_t c = 0; c < C; ++c) line[c] = x[(o * C + c) * inner + i];
      f(line);
      for (int64_t c = 0; c < C; ++c) y[(o * C + c) * inner + i] = line[c];
    }
  return y;
}

std::vector<double> softmaxRef(const std::vector<float>& x, int64_t outer, int64_t C, int64_t inner) {
  return perLine(x, outer, C, inner, [](std::vector<double>& v) {
    double m = -std::numeric_limits<double>::infinity(), s = 0;
    for (double t : v) m = std::max(m, t);
    for (double t : v) s += std::exp(t - m);
    for (double& t : v) t = std::exp(t - m) / s;
  });
}

std::vector<double> l2Ref(const std::vector<float>& x, int64_t outer, int64_t C, int64_t inner, double eps) {
  return perLine(x, outer, C, inner, [eps](std::vector<double>& v) {
    double s = 0;
    for (double t : v) s += t * t;  // double holds (3.4e38)^2
    const double norm = std::max(std::sqrt(s), eps);
    for (double& t : v) t /= norm;
  });
}

// torch.argmax: first index of the maximum, NaN above everything.
std::vector<int32_t> argmaxRef(const std::vector<float>& x, int64_t outer, int64_t C, int64_t inner) {
  std::vector<int32_t> idx(outer * inner);
  for (int64_t o = 0; o < outer; ++o)
    for (int64_t i = 0; i < inner; ++i) {
      int32_t best = 0;
      for (int64_t c = 1; c < C; ++c) {
        const float v = x[(o * C + c) * inner + i], b = x[(o * C + best) * inner + i];
        if ((std::isnan(v) && !std::isnan(b)) || v > b) best = int32_t(c);
      }
      idx[o * inner + i] = best;
    }
  return idx;
}

std::vector<int32_t> readIndices(Engine& engine, const Tensor& t) {
  std::vector<int32_t> v(t.numel());
  engine.read(t, v.data(), v.size() * 4);
  return v;
}

// A tensor of shape `shape` reduced along `axis`, as [outer, C, inner].
struct AxisCase {
  Shape shape;
  int axis;
};
// Readable, stable CTest names.
void PrintTo(const AxisCase& c, std::ostream* os) {
  for (size_t i = 0; i < c.shape.size(); ++i) *os << (i ? "x" : "") << c.shape[i];
  *os << "_axis" << c.axis;
}

void splitShape(const AxisCase& c, int64_t& outer, int64_t& C, int64_t& inner) {
  const int r = static_cast<int>(c.shape.size()), a = c.axis < 0 ? c.axis + r : c.axis;
  outer = inner = 1;
  for (int i = 0; i < a; ++i) outer *= c.shape[i];
  C = c.shape[a];
  for (int i = a + 1; i < r; ++i) inner *= c.shape[i];
}

std::string caseName(const AxisCase& c) { return shapeString(c.shape) + " axis " + std::to_string(c.axis); }

// Last-dimension rows (split and per-invocation lines) and NCHW channels (few and many lines).
const auto kAxisCases =
    ::testing::Values(AxisCase{{7, 7}, -1}, AxisCase{{61, 61}, -1}, AxisCase{{257, 257}, 1}, AxisCase{{3, 1000}, -1},
                      AxisCase{{1000, 3}, -1}, AxisCase{{61, 8}, -1}, AxisCase{{1}, 0}, AxisCase{{2, 61, 7, 9}, 1},
                      AxisCase{{2, 7, 61, 67}, 1}, AxisCase{{1, 64, 80, 80}, 1}, AxisCase{{3, 5, 7}, 0});

class AxisTest : public EngineTest, public ::testing::WithParamInterface<AxisCase> {};

TEST_P(AxisTest, SoftmaxMatchesFloat64Reference) {
  const auto c = GetParam();
  int64_t outer, C, inner;
  splitShape(c, outer, C, inner);
  auto x = randomUniform(shapeNumel(c.shape), -8, 8, 51);
  Tensor tx = eng().fromFloats(c.shape, x);
  GuardedOutput y(eng(), c.shape);
  Recorder rec(eng());
  softmax(rec, tx, y.tensor(), c.axis);
  rec.run();
  expectClose(y.read(), softmaxRef(x, outer, C, inner), 1e-9, 1e-6, "softmax " + caseName(c));
  y.expectAllWritten();
}

TEST_P(AxisTest, L2NormalizeMatchesFloat64Reference) {
  const auto c = GetParam();
  int64_t outer, C, inner;
  splitShape(c, outer, C, inner);
  auto x = randomNormal(shapeNumel(c.shape), 0.3f, 2.0f, 52);
  Tensor tx = eng().fromFloats(c.shape, x);
  GuardedOutput y(eng(), c.shape);
  Recorder rec(eng());
  l2Normalize(rec, tx, y.tensor(), c.axis);
  rec.run();
  expectClose(y.read(), l2Ref(x, outer, C, inner, 1e-12), 1e-9, 1e-6, "l2 " + caseName(c));
  y.expectAllWritten();
}

TEST_P(AxisTest, ArgmaxMatchesReference) {
  const auto c = GetParam();
  int64_t outer, C, inner;
  splitShape(c, outer, C, inner);
  auto x = randomNormal(shapeNumel(c.shape), 0.0f, 1.0f, 53);
  Tensor tx = eng().fromFloats(c.shape, x);
  Tensor idx = eng().tensor({outer * inner}, DType::I32);
  Recorder rec(eng());
  argmax(rec, tx, idx, c.axis);
  rec.run();
  EXPECT_EQ(readIndices(eng(), idx), argmaxRef(x, outer, C, inner)) << caseName(c);
}

INSTANTIATE_TEST_SUITE_P(Shapes, AxisTest, kAxisCases);

// Logits of +-1e4: max subtraction keeps exp finite; the result is (nearly) one-hot.
TEST_F(EngineTest, SoftmaxLogitsPlusMinus1e4) {
  for (int64_t C : {7, 61, 257, 256}) {
    const int64_t rows = 61;
    auto u = randomUniform(rows * C, -1, 1, 54);
    std::vector<float> x(u.size());
    for (size_t i = 0; i < u.size(); ++i) {
      // Row kinds: signs of 1e4, the full range [-1e4, 1e4], and 1e4 plus small offsets.
      const int64_t kind = int64_t(i / C) % 3;
      x[i] = kind == 0 ? (u[i] < 0 ? -1e4f : 1e4f) : kind == 1 ? u[i] * 1e4f : 1e4f + u[i] * 4.0f;
    }
    Tensor tx = eng().fromFloats({rows, C}, x);
    GuardedOutput y(eng(), {rows, C});
    Recorder rec(eng());
    softmax(rec, tx, y.tensor());
    rec.run();
    expectClose(y.read(), softmaxRef(x, rows, C, 1), 1e-9, 1e-6, "logits +-1e4 C=" + std::to_string(C));
    y.expectAllWritten();
  }
}

// One logit far above the rest: its probability is 1 to fp32 precision, the others tiny but exact in relative terms.
TEST_F(EngineTest, SoftmaxOneElementDominates) {
  for (int64_t C : {7, 61, 257, 64}) {
    const int64_t rows = 7;
    auto x = randomUniform(rows * C, -1, 1, 55);
    for (int64_t r = 0; r < rows; ++r) x[r * C + (r * 13) % C] += 30.0f + 10.0f * float(r);  // up to +90
    Tensor tx = eng().fromFloats({rows, C}, x);
    GuardedOutput y(eng(), {rows, C});
    Recorder rec(eng());
    softmax(rec, tx, y.tensor());
    rec.run();
    auto out = y.read();
    auto ref = softmaxRef(x, rows, C, 1);
    expectClose(out, ref, 1e-9, 1e-6, "dominant C=" + std::to_string(C));
    // The small probabilities keep their relative accuracy (until they fall below fp32's normal range).
    for (size_t i = 0; i < ref.size(); ++i) {
      if (ref[i] > 1e-30) {
        ASSERT_NEAR(out[i] / ref[i], 1.0, 1e-5) << "element " << i << " ref " << ref[i];
      }
    }
  }
}

// -inf entries get probability 0; a line with nothing but -inf gives zeros (not NaN).
TEST_F(EngineTest, SoftmaxMaskedEntries) {
  for (int64_t C : {61, 64}) {
    const int64_t rows = 4;
    const float inf = std::numeric_limits<float>::infinity();
    auto x = randomUniform(rows * C, -3, 3, 56);
    for (int64_t j = 0; j < C; j += 2) x[j] = -inf;   // row 0: half masked
    for (int64_t j = 0; j < C; ++j) x[C + j] = -inf;  // row 1: all masked
    x[2 * C + 5] = -inf;
    Tensor tx = eng().fromFloats({rows, C}, x);
    GuardedOutput y(eng(), {rows, C});
    Recorder rec(eng());
    softmax(rec, tx, y.tensor());
    rec.run();
    auto out = y.read();
    auto ref = softmaxRef(x, rows, C, 1);
    for (int64_t j = 0; j < C; ++j) ref[C + j] = 0.0;  // the kernel's convention for an all-masked line
    expectClose(out, ref, 1e-9, 1e-6, "masked C=" + std::to_string(C));
    for (int64_t j = 0; j < C; j += 2) ASSERT_EQ(out[j], 0.0f);
    for (int64_t j = 0; j < C; ++j) ASSERT_EQ(out[C + j], 0.0f);
  }
}

TEST_F(EngineTest, SoftmaxInPlace) {
  for (int64_t T : {61, 64}) {
    const int64_t B = 3, H = 4;
    auto x = randomUniform(B * H * T * T, -20, 20, 57);
    Tensor tx = eng().fromFloats({B, H, T, T}, x);
    Recorder rec(eng());
    softmax(rec, tx, tx);
    rec.run();
    expectClose(eng().download(tx), softmaxRef(x, B * H * T, T, 1), 1e-9, 1e-6, "in place T=" + std::to_string(T));
  }
}

// More workgroups than one grid dimension holds (65535 on lavapipe): a 2-D grid.
// (On lavapipe short lines go one per invocation, 64 a workgroup: 67188 workgroups.)
TEST_F(EngineTest, SoftmaxManyRowsUse2DGrid) {
  const int64_t rows = 4300000, C = 2;
  auto x = randomUniform(rows * C, -5, 5, 58);
  Tensor tx = eng().fromFloats({rows, C}, x);
  GuardedOutput y(eng(), {rows, C});
  Recorder rec(eng());
  softmax(rec, tx, y.tensor());
  rec.run();
  expectClose(y.read(), softmaxRef(x, rows, C, 1), 1e-9, 1e-6, "4.3M rows");
  y.expectAllWritten();
}

TEST_F(EngineTest, SoftmaxSplitIntoChunks) {
  // One image is 7 x 64 x 4 bytes, a multiple of 256: chunks of 2 images start where any
  // device may bind (minStorageBufferOffsetAlignment is at most 256).
  const int64_t N = 5, C = 7, HW = 64;
  auto x = randomUniform(N * C * HW, -5, 5, 59);
  Tensor tx = eng().fromFloats({N, C, HW}, x);
  GuardedOutput y(eng(), {N, C, HW});
  ScopedBindingRange lowered(eng(), 2 * C * HW * 4);  // 2 images a chunk: 3 chunks
  Recorder rec(eng());
  softmax(rec, tx, y.tensor(), 1);
  EXPECT_EQ(rec.pending(), 3u);
  rec.run();
  lowered.restore();
  expectClose(y.read(), softmaxRef(x, N, C, HW), 1e-9, 1e-6, "chunked");
  y.expectAllWritten();
}

// Values around 1e30 and up to FLT_MAX: squaring them overflows fp32, scaling by max |x| does not.
TEST_F(EngineTest, L2NormalizeHugeValues) {
  for (const AxisCase& c :
       {AxisCase{{7, 257}, -1}, AxisCase{{7, 256}, -1}, AxisCase{{2, 61, 7, 9}, 1}, AxisCase{{5, 7}, -1}}) {
    int64_t outer, C, inner;
    splitShape(c, outer, C, inner);
    auto x = randomNormal(shapeNumel(c.shape), 0.0f, 1e30f, 60);
    for (size_t i = 0; i < x.size(); i += 17) x[i] = (i % 2 ? -1.0f : 1.0f) * 3.0e38f;
    Tensor tx = eng().fromFloats(c.shape, x);
    GuardedOutput y(eng(), c.shape);
    Recorder rec(eng());
    l2Normalize(rec, tx, y.tensor(), c.axis);
    rec.run();
    expectClose(y.read(), l2Ref(x, outer, C, inner, 1e-12), 1e-9, 1e-6, "huge " + caseName(c));
    y.expectAllWritten();
  }
}

// An all-zero vector stays zero (x / eps); a vector with norm below eps is divided by eps.
TEST_F(EngineTest, L2NormalizeZeroAndTinyVectors) {
  for (int64_t C : {61, 64}) {
    const int64_t rows = 4;
    auto x = randomNormal(rows * C, 0.0f, 1.0f, 61);
    for (int64_t j = 0; j < C; ++j) x[j] = 0.0f;                               // row 0: zeros
    for (int64_t j = 0; j < C; ++j) x[C + j] *= 1e-15f;                        // row 1: norm ~8e-15 < eps
    for (int64_t j = 0; j < C; ++j) x[2 * C + j] = j == 3 ? -2.5e-13f : 0.0f;  // row 2: one tiny value
    Tensor tx = eng().fromFloats({rows, C}, x);
    GuardedOutput y(eng(), {rows, C});
    Recorder rec(eng());
    l2Normalize(rec, tx, y.tensor(), -1);
    rec.run();
    auto out = y.read();
    expectClose(out, l2Ref(x, rows, C, 1, 1e-12), 1e-9, 1e-6, "zero and tiny C=" + std::to_string(C));
    for (int64_t j = 0; j < C; ++j) ASSERT_EQ(out[j], 0.0f);
    y.expectAllWritten();
  }
}

TEST_F(EngineTest, L2NormalizeInPlace) {
  const int64_t N = 2, C = 61, HW = 257;
  auto x = randomNormal(N * C * HW, 0.0f, 3.0f, 62);
  Tensor tx = eng().fromFloats({N, C, HW}, x);
  Recorder rec(eng());
  l2Normalize(rec, tx, tx, 1);
  rec.run();
  expectClose(eng().download(tx), l2Ref(x, N, C, HW, 1e-12), 1e-9, 1e-6, "in place");
}

// Ties go to the first index, whichever invocation saw them (lines split across lanes or not).
TEST_F(EngineTest, ArgmaxTies) {
  for (const AxisCase& c : {AxisCase{{7, 257}, -1}, AxisCase{{7, 256}, -1}, AxisCase{{61, 7}, -1},
                            AxisCase{{61, 8}, -1}, AxisCase{{2, 61, 7, 9}, 1}, AxisCase{{1, 61, 80, 80}, 1}}) {
    int64_t outer, C, inner;
    splitShape(c, outer, C, inner);
    // Few distinct levels: every line has its maximum several times.
    auto u = randomUniform(shapeNumel(c.shape), 0, 4, 63);
    std::vector<float> x(u.size());
    for (size_t i = 0; i < u.size(); ++i) x[i] = std::floor(u[i]);
    // Lines whose maximum appears only at the end, and lines that are constant.
    for (int64_t i = 0; i < inner; ++i) {
      for (int64_t ch = 0; ch < C; ++ch) x[ch * inner + i] = i % 2 ? 5.0f : -1.0f;
      if (i % 2 == 0) x[(C - 1) * inner + i] = 0.0f;
    }
    Tensor tx = eng().fromFloats(c.shape, x);
    Tensor idx = eng().tensor({outer * inner}, DType::I32);
    Recorder rec(eng());
    argmax(rec, tx, idx, c.axis);
    rec.run();
    EXPECT_EQ(readIndices(eng(), idx), argmaxRef(x, outer, C, inner)) << caseName(c);
  }
}

// NaN counts as the maximum (torch.argmax); the first NaN wins. -inf lines give index 0.
TEST_F(EngineTest, ArgmaxNaNAndInfinity) {
  for (int64_t C : {61, 64}) {
    const int64_t rows = 4;
    const float inf = std::numeric_limits<float>::infinity(), nan = std::numeric_limits<float>::quiet_NaN();
    auto x = randomUniform(rows * C, -1, 1, 64);
    x[10] = nan;
    x[40] = nan;
    x[20] = inf;                                      // row 0: NaN at 10 beats +inf
    for (int64_t j = 0; j < C; ++j) x[C + j] = -inf;  // row 1: all -inf -> 0
    x[2 * C + 33] = inf;
    x[2 * C + 50] = inf;  // row 2: first +inf
    Tensor tx = eng().fromFloats({rows, C}, x);
    Tensor idx = eng().tensor({rows}, DType::I32);
    Recorder rec(eng());
    argmax(rec, tx, idx, -1);
    rec.run();
    auto got = readIndices(eng(), idx);
    EXPECT_EQ(got, argmaxRef(x, rows, C, 1)) << "C=" << C;
    EXPECT_EQ(got[0], 10);
    EXPECT_EQ(got[1], 0);
    EXPECT_EQ(got[2], 33);
  }
}

// The workgroup shapes other devices get (lines split over 16-64 invocations, several lines
// a workgroup) give the same results as lavapipe's.
TEST_F(EngineTest, ReduceChannelsWorkgroupShapesAgree) {
  // {1, LX, 1}: one split line a workgroup, the subgroup-reduction variants where the plan has
  // them (the GPU family: SPAR_KERNELS=gpu).
  const KernelTuning saved = eng().options().tuning;
  for (const std::array<int, 3> group :
       {std::array{1, 16, 4}, {1, 64, 2}, {1, 8, 3}, {0, 16, 2}, {0, 8, 1}, {1, 64, 1}, {1, 8, 1}}) {
    KernelTuning tuning = saved;
    tuning.lineGroup = group;
    eng().setTuning(tuning);
    const std::string shape = std::to_string(group[0]) + "," + std::to_string(group[1]) + "," + std::to_string(group[2]);
    for (const AxisCase& c :
         {AxisCase{{29, 7}, -1}, AxisCase{{29, 256}, -1}, AxisCase{{29, 257}, -1}, AxisCase{{2, 61, 7, 9}, 1}}) {
      int64_t outer, C, inner;
      splitShape(c, outer, C, inner);
      auto u = randomUniform(shapeNumel(c.shape), -4, 4, 65);
      std::vector<float> x(u.size());
      for (size_t i = 0; i < u.size(); ++i) x[i] = i % 3 ? u[i] : std::floor(u[i]);  // ties for argmax
      Tensor tx = eng().fromFloats(c.shape, x);
      GuardedOutput sm(eng(), c.shape), l2(eng(), c.shape);
      Tensor idx = eng().tensor({outer * inner}, DType::I32);
      Recorder rec(eng());
      softmax(rec, tx, sm.tensor(), c.axis);
      l2Normalize(rec, tx, l2.tensor(), c.axis);
      argmax(rec, tx, idx, c.axis);
      rec.run();
      const std::string what = shape + " " + caseName(c);
      expectClose(sm.read(), softmaxRef(x, outer, C, inner), 1e-9, 1e-6, "softmax " + what);
      expectClose(l2.read(), l2Ref(x, outer, C, inner, 1e-12), 1e-9, 1e-6, "l2 " + what);
      EXPECT_EQ(readIndices(eng(), idx), argmaxRef(x, outer, C, inner)) << what;
      sm.expectAllWritten();
      l2.expectAllWritten();
    }
  }
  eng().setTuning(saved);
}

TEST_F(EngineTest, ReduceChannelsRejectsBadShapes) {
  Tensor x = eng().tensor({4, 8}), y = eng().tensor({8, 4}), idx = eng().tensor({5}, DType::I32);
  Tensor idxF = eng().tensor({4});
  Recorder rec(eng());
  EXPECT_THROW(softmax(rec, x, y), Error);
  EXPECT_THROW(softmax(rec, x, eng().tensor({4, 8}), 2), Error);
  EXPECT_THROW(l2Normalize(rec, x, eng().tensor({4, 8}), 1, 0.0f), Error);
  EXPECT_THROW(argmax(rec, x, idx, 1), Error);
  EXPECT_THROW(argmax(rec, x, idxF, 1), Error);
  EXPECT_THROW(argmax(rec, eng().tensor({4, 0}), eng().tensor({4}, DType::I32), 1), Error);
  EXPECT_EQ(rec.pending(), 0u);
}

}  // namespace
}  // namespace spar::test
