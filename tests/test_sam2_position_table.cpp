// model/sam2_position_table (SAM2.1's Hiera position table) against a float64 CPU sum of
// PyTorch's bicubic (align_corners=False: unclamped source, clamped taps, A = -0.75) plus the
// tiled window table, the formula reference/spar_reference/sam2.py position_embedding runs
// and reference/tests/test_reference_sam2.py checks the same way. Odd sizes: 7x7 to 24 (scale
// 7/24), the b+ 14x14 table with an odd window of 7, a downsampling 7 -> 4 (sources below 0),
// and hiera_t's real 96 x 256^2.
#include <cmath>

#include "model/sam2_position_table.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

double cubic(double x) {
  constexpr double A = -0.75;
  x = std::abs(x);
  if (x <= 1) return ((A + 2) * x - (A + 3)) * x * x + 1;
  if (x < 2) return ((A * x - 5 * A) * x + 8 * A) * x - 4 * A;
  return 0;
}

// [out][in] weights of one axis.
std::vector<std::vector<double>> axisWeights(int64_t in, int64_t out) {
  std::vector<std::vector<double>> w(size_t(out), std::vector<double>(size_t(in), 0.0));
  for (int64_t o = 0; o < out; ++o) {
    const double src = (double(o) + 0.5) * double(in) / double(out) - 0.5;
    const double f = std::floor(src);
    for (int k = -1; k <= 2; ++k) {
      const int64_t tap = std::clamp(int64_t(f) + k, int64_t(0), in - 1);
      w[size_t(o)][size_t(tap)] += cubic(double(k) - (src - f));
    }
  }
  return w;
}

std::vector<double> referenceTable(const std::vector<float>& bg, const std::vector<float>& win, int64_t C, int64_t bh,
                                   int64_t bw, int64_t w, int64_t side) {
  const auto wy = axisWeights(bh, side), wx = axisWeights(bw, side);
  std::vector<double> out(size_t(side * side * C));
  for (int64_t y = 0; y < side; ++y)
    for (int64_t x = 0; x < side; ++x)
      for (int64_t c = 0; c < C; ++c) {
        double acc = 0;
        for (int64_t i = 0; i < bh; ++i) {
          if (wy[size_t(y)][size_t(i)] == 0) continue;
          double row = 0;
          for (int64_t j = 0; j < bw; ++j) row += wx[size_t(x)][size_t(j)] * bg[size_t((c * bh + i) * bw + j)];
          acc += wy[size_t(y)][size_t(i)] * row;
        }
        out[size_t((y * side + x) * C + c)] = acc + win[size_t((c * w + y % w) * w + x % w)];
      }
  return out;
}

class Sam2PositionTableTest : public EngineTest {
 protected:
  // fp32 against float64: 16 taps of O(1) values; measured NMSE ~1e-15, max abs ~1e-6.
  void check(int64_t C, int64_t bh, int64_t bw, int64_t w, int64_t side, uint32_t seed) {
    const std::vector<float> bg = randomUniform(size_t(C * bh * bw), -1.0f, 1.0f, seed);
    const std::vector<float> win = randomUniform(size_t(C * w * w), -1.0f, 1.0f, seed + 1);
    Tensor tb = eng().fromFloats({1, C, bh, bw}, bg), tw = eng().fromFloats({1, C, w, w}, win);
    GuardedOutput out(eng(), {side * side, C});
    Recorder rec(eng());
    sam2PositionTable(rec, tb, tw, out.tensor());
    rec.run();
    out.expectAllWritten();
    expectClose(out.read(), referenceTable(bg, win, C, bh, bw, w, side), 1e-12, 1e-5,
                "position table " + std::to_string(bh) + "x" + std::to_string(bw) + " -> " + std::to_string(side));
  }
};

TEST_F(Sam2PositionTableTest, SevenToTwentyFourOddChannels) { check(5, 7, 7, 4, 24, 3); }
TEST_F(Sam2PositionTableTest, FourteenWithAnOddWindow) { check(3, 14, 14, 7, 28, 5); }
TEST_F(Sam2PositionTableTest, DownsamplingReadsBelowZero) { check(2, 7, 7, 2, 4, 7); }
TEST_F(Sam2PositionTableTest, HieraTinyAtFullSize) { check(96, 7, 7, 8, 256, 11); }

TEST_F(Sam2PositionTableTest, RefusesWhatDoesNotFit) {
  Tensor bg = eng().tensor({1, 4, 7, 7}), win = eng().tensor({1, 4, 3, 3});
  Recorder rec(eng());
  EXPECT_THROW(sam2PositionTable(rec, bg, win, eng().tensor({16 * 16, 4})), Error);  // 3 does not tile 16
  EXPECT_THROW(sam2PositionTable(rec, bg, eng().tensor({1, 5, 3, 3}), eng().tensor({9 * 9, 4})), Error);
  EXPECT_THROW(sam2PositionTable(rec, bg, win, eng().tensor({80, 4})), Error);  // not a square
  EXPECT_THROW(sam2PositionTable(rec, bg, win, eng().tensor({81, 5})), Error);
}

}  // namespace
}  // namespace spar::test
