// avgPool2d (shaders/pool.comp via engine/ops/pool.cpp) against a float64 reference.
#include "engine/ops/pool.h"

#include "tests/test_support.h"

namespace spar::test {
namespace {

std::vector<double> avgPoolRef(const std::vector<float>& x, int64_t NC, int64_t H, int64_t W, int k) {
  const int64_t Ho = H / k, Wo = W / k;
  std::vector<double> y(NC * Ho * Wo);
  for (int64_t p = 0; p < NC; ++p)
    for (int64_t oy = 0; oy < Ho; ++oy)
      for (int64_t ox = 0; ox < Wo; ++ox) {
        double s = 0;
        for (int i = 0; i < k; ++i)
          for (int j = 0; j < k; ++j) s += x[(p * H + oy * k + i) * W + ox * k + j];
        y[(p * Ho + oy) * Wo + ox] = s / (k * k);
      }
  return y;
}

struct PoolCase {
  int64_t N, C, H, W;
  int k;
};

// Readable test names and failure messages.
std::string describe(const PoolCase& c) {
  return "N" + std::to_string(c.N) + "_C" + std::to_string(c.C) + "_" + std::to_string(c.H) +
         "x" + std::to_string(c.W) + "_k" + std::to_string(c.k);
}
void PrintTo(const PoolCase& c, std::ostream* os) { *os << describe(c); }

class AvgPool2dTest : public EngineTest, public ::testing::WithParamInterface<PoolCase> {};

TEST_P(AvgPool2dTest, MatchesFloat64Reference) {
  const auto c = GetParam();
  auto x = randomUniform(c.N * c.C * c.H * c.W, -1, 1, 1);
  Tensor tx = eng().fromFloats({c.N, c.C, c.H, c.W}, x);
  GuardedOutput y(eng(), {c.N, c.C, c.H / c.k, c.W / c.k});
  Recorder rec(eng());
  avgPool2d(rec, tx, y.tensor(), c.k);
  rec.run();
  expectClose(y.read(), avgPoolRef(x, c.N * c.C, c.H, c.W, c.k), 1e-10, 1e-6, "avg pool");
  y.expectAllWritten();
}

// Remainder rows and columns (H % k, W % k) are dropped, as nn.AvgPool2d does.
INSTANTIATE_TEST_SUITE_P(Sizes, AvgPool2dTest,
                         ::testing::Values(PoolCase{1, 7, 13, 13, 2}, PoolCase{2, 61, 17, 23, 3},
                                           PoolCase{1, 3, 64, 64, 4}, PoolCase{2, 5, 61, 37, 7},
                                           PoolCase{1, 2, 14, 70, 14}, PoolCase{1, 3, 9, 5, 1},
                                           PoolCase{1, 4, 5, 5, 5}),
                         [](const ::testing::TestParamInfo<PoolCase>& info) { return describe(info.param); });

// The mean of a constant window is that constant, exactly.
TEST_F(EngineTest, AvgPool2dConstantImagesStayExact) {
  for (float value : {0.0f, 1.0f}) {
    for (int k : {2, 3, 7}) {
      const int64_t N = 1, C = 3, H = 23, W = 29;
      std::vector<float> x(N * C * H * W, value);
      Tensor tx = eng().fromFloats({N, C, H, W}, x);
      GuardedOutput y(eng(), {N, C, H / k, W / k});
      Recorder rec(eng());
      avgPool2d(rec, tx, y.tensor(), k);
      rec.run();
      expectClose(y.read(), std::vector<double>(N * C * (H / k) * (W / k), value), 0.0, 0.0,
                  value == 0 ? "black image" : "white image");
    }
  }
}

TEST_F(EngineTest, AvgPool2dRejectsBadShapes) {
  Tensor x = eng().tensor({1, 3, 8, 9});
  Recorder rec(eng());
  EXPECT_THROW(avgPool2d(rec, x, eng().tensor({1, 3, 4, 5}), 2), Error);  // floor(9/2) = 4
  EXPECT_THROW(avgPool2d(rec, x, eng().tensor({1, 3, 0, 0}), 10), Error);  // kernel larger than input
  EXPECT_THROW(avgPool2d(rec, x, eng().tensor({1, 3, 8, 9}), 0), Error);
  EXPECT_THROW(avgPool2d(rec, eng().tensor({3, 8, 9}), eng().tensor({3, 4, 4}), 2), Error);
  EXPECT_EQ(rec.pending(), 0u);
}

}  // namespace
}  // namespace spar::test
