// The inputs of SAM2.1's image encoder on the engine, against float64 CPU sums of the official
// steps (reference/spar_reference/sam2.py computes the same, checked by
// reference/tests/test_reference_sam2.py):
//  * model/sam2_preprocess: SPAR's uint8 cast (x 255 in float32, truncated), bilinear resize
//    with PyTorch's align_corners=False (source clamped at 0, last tap clamped), ImageNet
//    mean/std. Odd sizes, SAM2's 256 -> 1024, every k / 255 recovered exactly, 0.999 -> 254.
//  * model/sam2_position_table: PyTorch's bicubic (align_corners=False: unclamped source,
//    clamped taps, A = -0.75) of the background table plus the tiled window table. 7x7 to 24
//    (scale 7/24), the b+ 14x14 table with an odd window of 7, a downsampling 7 -> 4 (sources
//    below 0), and hiera_t's real 96 x 256^2.
#include <algorithm>
#include <cmath>

#include "model/sam2_position_table.h"
#include "model/sam2_preprocess.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

constexpr double kMean[3] = {0.485, 0.456, 0.406}, kStd[3] = {0.229, 0.224, 0.225};

std::vector<double> reference(const std::vector<float>& img, int64_t view, int64_t H, int64_t W, int64_t oh, int64_t ow) {
  auto u8 = [&](int64_t c, int64_t y, int64_t x) {
    const float v = img[size_t(((view * 3 + c) * H + y) * W + x)] * 255.0f;  // float32, as numpy's
    return double(uint32_t(std::clamp(v, 0.0f, 255.0f)));
  };
  std::vector<double> out(size_t(3 * oh * ow));
  for (int64_t c = 0; c < 3; ++c)
    for (int64_t y = 0; y < oh; ++y)
      for (int64_t x = 0; x < ow; ++x) {
        const double sy = std::max((y + 0.5) * double(H) / double(oh) - 0.5, 0.0);
        const double sx = std::max((x + 0.5) * double(W) / double(ow) - 0.5, 0.0);
        const int64_t y0 = int64_t(sy), x0 = int64_t(sx), y1 = std::min(y0 + 1, H - 1), x1 = std::min(x0 + 1, W - 1);
        const double ly = sy - y0, lx = sx - x0;
        const double v = ((1 - ly) * ((1 - lx) * u8(c, y0, x0) + lx * u8(c, y0, x1)) +
                          ly * ((1 - lx) * u8(c, y1, x0) + lx * u8(c, y1, x1))) / 255.0;
        out[size_t((c * oh + y) * ow + x)] = (v - kMean[c]) / kStd[c];
      }
  return out;
}

class Sam2PreprocessTest : public EngineTest {
 protected:
  std::vector<float> run(const std::vector<float>& img, int64_t V, int64_t view, int64_t H, int64_t W, int64_t oh,
                         int64_t ow) {
    Tensor t = eng().fromFloats({V, 3, H, W}, img);
    GuardedOutput out(eng(), {3, oh, ow});
    Recorder rec(eng());
    sam2Preprocess(rec, t, view, out.tensor());
    rec.run();
    out.expectAllWritten();
    return out.read();
  }
  // fp32 against float64, the resize op's thresholds (tests/test_resize.cpp) scaled by 1/std
  // (4.4): the source coordinate (dst + 0.5) * in/out is computed in fp32, as PyTorch's float
  // kernels do, which at a scale like 37/96 moves it by ~1e-5 pixel (measured NMSE 1.9e-12,
  // max abs 1.1e-5); at SAM2's 256 -> 1024 the scale is exact (measured 9e-15, 4.8e-7).
  void check(int64_t V, int64_t view, int64_t H, int64_t W, int64_t oh, int64_t ow) {
    const std::vector<float> img = randomUniform(size_t(V * 3 * H * W), 0.0f, 1.0f, uint32_t(H * W));
    expectClose(run(img, V, view, H, W, oh, ow), reference(img, view, H, W, oh, ow), 1e-10, 5e-5,
                "preprocess " + std::to_string(H) + "x" + std::to_string(W) + " -> " + std::to_string(oh) + "x" +
                    std::to_string(ow));
  }
};

TEST_F(Sam2PreprocessTest, OddSizesSecondView) { check(2, 1, 37, 53, 96, 128); }
TEST_F(Sam2PreprocessTest, SparSizeTo1024) { check(1, 0, 256, 256, 1024, 1024); }

TEST_F(Sam2PreprocessTest, EveryByteRecoveredAndTruncated) {
  // k / 255 for every k, at the identity size: the output is exactly (k / 255 - mean) / std
  const int64_t H = 16, W = 16;
  std::vector<float> img(size_t(3 * H * W));
  for (size_t i = 0; i < img.size(); ++i) img[i] = float(i % 256) / 255.0f;
  img[5] = 0.999f;  // 254.745 truncates to 254
  const std::vector<float> out = run(img, 1, 0, H, W, H, W);
  for (size_t i = 0; i < img.size(); ++i) {
    const size_t c = i / size_t(H * W);
    const double k = i == 5 ? 254.0 : double(i % 256);
    ASSERT_NEAR(out[i], (k / 255.0 - kMean[c]) / kStd[c], 2e-6) << "value " << i;
  }
}

TEST_F(Sam2PreprocessTest, RefusesDownsamplingAndBadViews) {
  Tensor img = eng().tensor({2, 3, 64, 64});
  Recorder rec(eng());
  EXPECT_THROW(sam2Preprocess(rec, img, 0, eng().tensor({3, 32, 32})), Error);
  EXPECT_THROW(sam2Preprocess(rec, img, 2, eng().tensor({3, 64, 64})), Error);
  EXPECT_THROW(sam2Preprocess(rec, img, -1, eng().tensor({3, 64, 64})), Error);
  EXPECT_THROW(sam2Preprocess(rec, eng().tensor({2, 4, 64, 64}), 0, eng().tensor({3, 64, 64})), Error);
}


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
