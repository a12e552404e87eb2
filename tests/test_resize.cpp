// resizeBilinear (shaders/resize.comp via engine/ops/resize.cpp) against a float64
// reference of PyTorch's F.interpolate(mode='bilinear', antialias=False) with a size.
#include "engine/ops/resize.h"

#include "tests/test_support.h"

namespace spar::test {
namespace {

// PyTorch's source index along one axis (area_pixel_compute_source_index, linear mode).
void sourceIndex(int64_t dst, int64_t in, int64_t out, bool alignCorners, int64_t& i0, int64_t& i1, double& l) {
  double src;
  if (alignCorners) {
    src = out > 1 ? double(dst) * double(in - 1) / double(out - 1) : 0.0;
  } else {
    src = (double(dst) + 0.5) * double(in) / double(out) - 0.5;
    if (src < 0) src = 0;
  }
  i0 = std::min<int64_t>(int64_t(src), in - 1);
  i1 = std::min<int64_t>(i0 + 1, in - 1);
  l = std::clamp(src - double(i0), 0.0, 1.0);
}

std::vector<double> resizeRef(const std::vector<float>& x, int64_t NC, int64_t H, int64_t W, int64_t Ho, int64_t Wo,
                              bool alignCorners) {
  std::vector<double> y(NC * Ho * Wo);
  for (int64_t p = 0; p < NC; ++p)
    for (int64_t oy = 0; oy < Ho; ++oy) {
      int64_t y0, y1;
      double ly;
      sourceIndex(oy, H, Ho, alignCorners, y0, y1, ly);
      for (int64_t ox = 0; ox < Wo; ++ox) {
        int64_t x0, x1;
        double lx;
        sourceIndex(ox, W, Wo, alignCorners, x0, x1, lx);
        auto at = [&](int64_t r, int64_t c) { return double(x[(p * H + r) * W + c]); };
        y[(p * Ho + oy) * Wo + ox] = (1 - ly) * ((1 - lx) * at(y0, x0) + lx * at(y0, x1)) +
                                     ly * ((1 - lx) * at(y1, x0) + lx * at(y1, x1));
      }
    }
  return y;
}

struct ResizeCase {
  int64_t N, C, H, W, Ho, Wo;
  bool alignCorners;
};

// Readable test names and failure messages.
std::string describe(const ResizeCase& c) {
  return "N" + std::to_string(c.N) + "_C" + std::to_string(c.C) + "_" + std::to_string(c.H) + "x" +
         std::to_string(c.W) + "_to_" + std::to_string(c.Ho) + "x" + std::to_string(c.Wo) +
         (c.alignCorners ? "_align_corners" : "");
}
void PrintTo(const ResizeCase& c, std::ostream* os) { *os << describe(c); }

class ResizeTest : public EngineTest, public ::testing::WithParamInterface<ResizeCase> {};

TEST_P(ResizeTest, MatchesFloat64Reference) {
  const auto c = GetParam();
  auto x = randomUniform(c.N * c.C * c.H * c.W, -1, 1, 1);
  Tensor tx = eng().fromFloats({c.N, c.C, c.H, c.W}, x);
  GuardedOutput y(eng(), {c.N, c.C, c.Ho, c.Wo});
  Recorder rec(eng());
  resizeBilinear(rec, tx, y.tensor(), c.alignCorners);
  rec.run();
  expectClose(y.read(), resizeRef(x, c.N * c.C, c.H, c.W, c.Ho, c.Wo, c.alignCorners), 1e-10, 1e-5,
              c.alignCorners ? "resize align_corners" : "resize");
  y.expectAllWritten();
}

INSTANTIATE_TEST_SUITE_P(
    Sizes, ResizeTest,
    ::testing::Values(ResizeCase{1, 3, 13, 17, 29, 61, false},   // up, non-integer ratios
                      ResizeCase{1, 3, 13, 17, 29, 61, true},
                      ResizeCase{2, 7, 61, 37, 17, 13, false},   // down
                      ResizeCase{2, 7, 61, 37, 17, 13, true},
                      ResizeCase{1, 5, 16, 16, 32, 32, false},   // exact 2x up
                      ResizeCase{1, 5, 16, 16, 32, 32, true},
                      ResizeCase{1, 2, 32, 24, 8, 6, false},     // exact 4x down
                      ResizeCase{1, 2, 14, 14, 518, 518, false}, // patch grid to image size
                      ResizeCase{1, 4, 7, 9, 1, 1, false},       // to one pixel
                      ResizeCase{1, 4, 7, 9, 1, 1, true},
                      ResizeCase{1, 3, 1, 1, 5, 7, false},       // from one pixel
                      ResizeCase{1, 3, 1, 1, 5, 7, true},
                      ResizeCase{3, 1, 9, 40, 20, 9, true}),     // up in y, down in x
    [](const ::testing::TestParamInfo<ResizeCase>& info) { return describe(info.param); });

// Same size with align_corners false is an exact copy (every source index is an integer).
TEST_F(EngineTest, ResizeSameSizeIsExactCopy) {
  const int64_t N = 2, C = 3, H = 13, W = 21;
  auto x = randomUniform(N * C * H * W, -1, 1, 2);
  Tensor tx = eng().fromFloats({N, C, H, W}, x);
  for (bool align : {false, true}) {
    GuardedOutput y(eng(), {N, C, H, W});
    Recorder rec(eng());
    resizeBilinear(rec, tx, y.tensor(), align);
    rec.run();
    expectClose(y.read(), toDouble(x), 0.0, 0.0, "same size");
  }
}

// Constant black (0) and white (1) images stay exactly constant at any size.
TEST_F(EngineTest, ResizeConstantImagesStayExact) {
  for (float value : {0.0f, 1.0f}) {
    for (bool align : {false, true}) {
      for (auto [Ho, Wo] : {std::pair<int64_t, int64_t>{61, 47}, {5, 3}, {518, 37}}) {
        const int64_t N = 1, C = 3, H = 29, W = 23;
        std::vector<float> x(N * C * H * W, value);
        Tensor tx = eng().fromFloats({N, C, H, W}, x);
        GuardedOutput y(eng(), {N, C, Ho, Wo});
        Recorder rec(eng());
        resizeBilinear(rec, tx, y.tensor(), align);
        rec.run();
        expectClose(y.read(), std::vector<double>(N * C * Ho * Wo, value), 0.0, 0.0,
                    value == 0 ? "black image" : "white image");
      }
    }
  }
}

TEST_F(EngineTest, ResizeOutputSplitIntoChunks) {
  const int64_t N = 2, C = 9, H = 10, W = 11, Ho = 23, Wo = 17;
  auto x = randomUniform(N * C * H * W, -1, 1, 3);
  Tensor tx = eng().fromFloats({N, C, H, W}, x);
  GuardedOutput y(eng(), {N, C, Ho, Wo});
  ScopedBindingRange lowered(eng(), uint64_t(5 * Ho * Wo) * 4);  // one block of 4 channels
  Recorder rec(eng());
  resizeBilinear(rec, tx, y.tensor(), false);
  EXPECT_GT(rec.pending(), 2u);
  rec.run();
  lowered.restore();
  expectClose(y.read(), resizeRef(x, N * C, H, W, Ho, Wo, false), 1e-10, 1e-5, "chunked");
  y.expectAllWritten();
}

TEST_F(EngineTest, ResizeRejectsBadShapes) {
  Tensor x = eng().tensor({1, 3, 8, 8});
  Recorder rec(eng());
  EXPECT_THROW(resizeBilinear(rec, x, eng().tensor({1, 4, 16, 16}), false), Error);  // channels differ
  EXPECT_THROW(resizeBilinear(rec, x, eng().tensor({2, 3, 16, 16}), false), Error);  // batch differs
  EXPECT_THROW(resizeBilinear(rec, x, eng().tensor({3, 16, 16}), false), Error);     // rank
  EXPECT_THROW(resizeBilinear(rec, eng().tensor({1, 3, 0, 8}), eng().tensor({1, 3, 4, 4}), false), Error);
  EXPECT_EQ(rec.pending(), 0u);
}

}  // namespace
}  // namespace spar::test
