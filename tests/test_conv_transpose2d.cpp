// convTranspose2d (shaders/conv_transpose2d.comp via engine/ops/conv_transpose2d.cpp)
// against a float64 reference.
#include "engine/ops/conv_transpose2d.h"

#include "tests/test_support.h"

namespace spar::test {
namespace {

struct ConvTCase {
  int64_t N, Cin, H, W, Cout, k;
  bool bias;
  Activation act;
};

// Readable test names and failure messages.
std::string describe(const ConvTCase& c) {
  return "N" + std::to_string(c.N) + "_Cin" + std::to_string(c.Cin) + "_" + std::to_string(c.H) + "x" +
         std::to_string(c.W) + "_Cout" + std::to_string(c.Cout) + "_k" + std::to_string(c.k) +
         (c.bias ? "_bias" : "") + "_act" + std::to_string(int(c.act));
}
void PrintTo(const ConvTCase& c, std::ostream* os) { *os << describe(c); }

// out[n,co,oy,ox] = act(b[co] + sum_ci in[n,ci,oy/k,ox/k] * w[ci,co,oy%k,ox%k])
std::vector<double> convTRef(const ConvTCase& c, const std::vector<float>& x, const std::vector<float>& w,
                             const std::vector<float>& b) {
  const int64_t Ho = c.H * c.k, Wo = c.W * c.k;
  std::vector<double> y(c.N * c.Cout * Ho * Wo);
  for (int64_t n = 0; n < c.N; ++n)
    for (int64_t co = 0; co < c.Cout; ++co)
      for (int64_t oy = 0; oy < Ho; ++oy)
        for (int64_t ox = 0; ox < Wo; ++ox) {
          double s = b.empty() ? 0.0 : b[co];
          for (int64_t ci = 0; ci < c.Cin; ++ci)
            s += double(x[((n * c.Cin + ci) * c.H + oy / c.k) * c.W + ox / c.k]) *
                 w[((ci * c.Cout + co) * c.k + oy % c.k) * c.k + ox % c.k];
          y[((n * c.Cout + co) * Ho + oy) * Wo + ox] = activateRef(s, c.act);
        }
  return y;
}

void runCase(Engine& eng, const ConvTCase& c, const std::vector<float>& x, const std::vector<float>& w,
             const std::vector<float>& b, double maxNmse, double maxAbs, const std::string& what) {
  Tensor tx = eng.fromFloats({c.N, c.Cin, c.H, c.W}, x), tw = eng.fromFloats({c.Cin, c.Cout, c.k, c.k}, w);
  Tensor tb = c.bias ? eng.fromFloats({c.Cout}, b) : Tensor();
  GuardedOutput y(eng, {c.N, c.Cout, c.H * c.k, c.W * c.k});
  Recorder rec(eng);
  convTranspose2d(rec, tx, tw, tb, y.tensor(), c.act);
  rec.run();
  expectClose(y.read(), convTRef(c, x, w, c.bias ? b : std::vector<float>{}), maxNmse, maxAbs, what);
  y.expectAllWritten();
}

class ConvTranspose2dTest : public EngineTest, public ::testing::WithParamInterface<ConvTCase> {};

TEST_P(ConvTranspose2dTest, MatchesFloat64Reference) {
  const auto c = GetParam();
  auto x = randomUniform(c.N * c.Cin * c.H * c.W, -1, 1, 1);
  auto w = randomUniform(c.Cin * c.Cout * c.k * c.k, -1, 1, 2);
  auto b = randomUniform(c.Cout, -1, 1, 3);
  runCase(eng(), c, x, w, b, 1e-8, 1e-4, "convTranspose2d");
}

// W % 4 == 0 cases read the input as RGBA texels; k = 3 reads the weights as R texels.
INSTANTIATE_TEST_SUITE_P(
    Shapes, ConvTranspose2dTest,
    ::testing::Values(ConvTCase{1, 7, 13, 13, 61, 2, true, Activation::None},
                      ConvTCase{2, 61, 7, 9, 7, 2, false, Activation::None},
                      ConvTCase{1, 64, 16, 16, 32, 2, true, Activation::Gelu},
                      ConvTCase{2, 13, 5, 11, 19, 4, true, Activation::None},
                      ConvTCase{1, 32, 8, 12, 61, 4, false, Activation::Silu},
                      ConvTCase{1, 5, 7, 8, 6, 3, true, Activation::None},
                      ConvTCase{3, 3, 1, 1, 2, 2, true, Activation::Sigmoid},
                      // The flat walk over input blocks (CPU tiles) wraps across block rows;
                      // Wo = 18 takes float stores, Wo = 20 vec4 stores with a partial last block.
                      ConvTCase{2, 6, 5, 9, 3, 2, true, Activation::Gelu},
                      ConvTCase{2, 6, 7, 10, 16, 2, true, Activation::Gelu}),
    [](const ::testing::TestParamInfo<ConvTCase>& info) { return describe(info.param); });

// CV-DRP's first up block at its full-size shape: 256 -> 128 channels from a 16x16 plane, 4
// images (a small plane with many channels: the flat walk fills the lanes).
TEST_F(EngineTest, ConvTranspose2dDecoderShape256From16x16) {
  const ConvTCase c{4, 256, 16, 16, 128, 2, true, Activation::Gelu};
  auto x = randomNormal(c.N * c.Cin * c.H * c.W, 0, 1, 31);
  auto w = randomNormal(c.Cin * c.Cout * 4, 0, 0.06f, 32);
  auto b = randomNormal(c.Cout, 0, 0.1f, 33);
  runCase(eng(), c, x, w, b, 1e-8, 1e-4, "256->128 k2 from 16x16, 4 images");
}

// The GPU tiles (2-D workgroups 16 x 8, 2 channels x 1 row x 4 columns, no flat walk) stay
// correct on this CPU device.
TEST_F(EngineTest, ConvTranspose2dGpuTilesMatchReference) {
  ScopedEnv tiles("SPAR_CONVT_TILES", "2,1,4,16,8");
  for (const ConvTCase& c : {ConvTCase{2, 6, 7, 10, 16, 2, true, Activation::Gelu},
                             ConvTCase{1, 7, 13, 13, 61, 2, true, Activation::None},
                             ConvTCase{2, 13, 5, 11, 19, 4, true, Activation::None}}) {
    auto x = randomUniform(c.N * c.Cin * c.H * c.W, -1, 1, 34);
    auto w = randomUniform(c.Cin * c.Cout * c.k * c.k, -1, 1, 35);
    auto b = randomUniform(c.Cout, -1, 1, 36);
    runCase(eng(), c, x, w, b, 1e-8, 1e-4, "GPU tiles " + describe(c));
  }
}

// An output view starting off a 4-element boundary takes float stores, on one vec4 stores;
// both match and nothing before the view is written.
TEST_F(EngineTest, ConvTranspose2dOutputAtAnyOffset) {
  const ConvTCase c{2, 5, 6, 8, 7, 2, true, Activation::None};
  auto x = randomUniform(c.N * c.Cin * c.H * c.W, -1, 1, 37), w = randomUniform(c.Cin * c.Cout * 4, -1, 1, 38);
  auto b = randomUniform(c.Cout, -1, 1, 39);
  const auto want = convTRef(c, x, w, b);
  Tensor tx = eng().fromFloats({c.N, c.Cin, c.H, c.W}, x), tw = eng().fromFloats({c.Cin, c.Cout, 2, 2}, w);
  Tensor tb = eng().fromFloats({c.Cout}, b);
  const Shape shape{c.N, c.Cout, c.H * 2, c.W * 2};
  for (int64_t off : {0, 1, 2, 3, 4}) {
    GuardedOutput y(eng(), {off + shapeNumel(shape)});
    Recorder rec(eng());
    convTranspose2d(rec, tx, tw, tb, y.tensor().view(off, shape));
    rec.run();
    const std::vector<float> all = y.read();
    for (int64_t i = 0; i < off; ++i) EXPECT_TRUE(std::isnan(all[size_t(i)])) << "wrote before the view, offset " << off;
    expectClose(std::vector<float>(all.begin() + off, all.end()), want, 1e-8, 1e-4, "offset " + std::to_string(off));
  }
}

TEST_F(EngineTest, ConvTranspose2dBlackImageGivesBias) {
  const ConvTCase c{2, 9, 7, 12, 13, 4, true, Activation::None};
  std::vector<float> x(c.N * c.Cin * c.H * c.W, 0.0f);
  auto w = randomUniform(c.Cin * c.Cout * 16, -1, 1, 4), b = randomUniform(c.Cout, -1, 1, 5);
  runCase(eng(), c, x, w, b, 0.0, 0.0, "black image");
}

TEST_F(EngineTest, ConvTranspose2dOutputSplitIntoChunks) {
  const ConvTCase c{3, 6, 5, 8, 21, 2, true, Activation::None};
  auto x = randomUniform(c.N * c.Cin * c.H * c.W, -1, 1, 6), w = randomUniform(c.Cin * c.Cout * 4, -1, 1, 7);
  auto b = randomUniform(c.Cout, -1, 1, 8);
  Tensor tx = eng().fromFloats({c.N, c.Cin, c.H, c.W}, x), tw = eng().fromFloats({c.Cin, c.Cout, 2, 2}, w);
  Tensor tb = eng().fromFloats({c.Cout}, b);
  GuardedOutput y(eng(), {c.N, c.Cout, c.H * 2, c.W * 2});
  // Room for just under one image's output: its channel blocks go to different dispatches.
  ScopedBindingRange lowered(eng(), uint64_t(c.Cout * c.H * 2 * c.W * 2) * 4);
  Recorder rec(eng());
  convTranspose2d(rec, tx, tw, tb, y.tensor());
  EXPECT_GT(rec.pending(), size_t(c.N));
  rec.run();
  lowered.restore();
  expectClose(y.read(), convTRef(c, x, w, b), 1e-8, 1e-4, "chunked");
  y.expectAllWritten();
}

// SwiftShader's transposed convolutions (KernelPlan::gemmLanesSplitK): the kernel and the
// input transposed by im2col's 1x1 patches, the lanes GEMM scattering its products into the
// k x k blocks (SCATTER_K) with the bias per channel; forced on this device through texel and
// storage inputs, constants written into the modules: k = 1, 2, 4, odd sizes, every
// activation, and an input in two bands of rows (256 channels x 64 columns: 63 rows a band of
// the 4 MiB scratch after the kernel).
TEST_F(EngineTest, ConvTranspose2dIm2colLanesGemmMatchesFloat64) {
  const DeviceCaps& caps = eng().caps();
  withLanesKernelsForced(eng(), [&](const std::string& inputs) {
    for (const ConvTCase& c : {ConvTCase{1, 7, 13, 13, 61, 2, true, Activation::None},
                               ConvTCase{2, 61, 7, 9, 7, 2, false, Activation::Gelu},
                               ConvTCase{2, 9, 7, 12, 13, 4, true, Activation::Silu},
                               ConvTCase{3, 5, 5, 3, 6, 1, true, Activation::Sigmoid},
                               ConvTCase{1, 16, 6, 10, 3, 2, true, Activation::QuickGelu},
                               ConvTCase{1, 3, 9, 7, 5, 2, false, Activation::Relu},
                               ConvTCase{1, 256, 70, 64, 8, 2, true, Activation::Gelu}}) {
      // texel inputs: only where an image fits one texel binding (SwiftShader's hold 65536)
      if (inputs == "texel" && uint64_t(c.Cin * c.H * c.W) > caps.maxTexelBufferElements) continue;
      auto x = randomUniform(c.N * c.Cin * c.H * c.W, -1, 1, 41), w = randomUniform(c.Cin * c.Cout * c.k * c.k, -1, 1, 42);
      auto b = randomUniform(c.Cout, -1, 1, 43);
      Tensor tx = eng().fromFloats({c.N, c.Cin, c.H, c.W}, x), tw = eng().fromFloats({c.Cin, c.Cout, c.k, c.k}, w);
      Tensor tb = c.bias ? eng().fromFloats({c.Cout}, b) : Tensor();
      GuardedOutput y(eng(), {c.N, c.Cout, c.H * c.k, c.W * c.k});
      Recorder rec(eng());
      convTranspose2d(rec, tx, tw, tb, y.tensor(), c.act);
      const int64_t bands = c.Cin == 256 ? 2 : 1;
      EXPECT_EQ(rec.pending(), size_t(1 + 2 * c.N * bands)) << describe(c);  // the kernel's im2col, then im2col and GEMM a band
      rec.run();
      expectClose(y.read(), convTRef(c, x, w, c.bias ? b : std::vector<float>{}), 1e-8, 1e-4,
                  "im2col, " + inputs + " inputs, " + describe(c));
      y.expectAllWritten();
    }
  });
}

TEST_F(EngineTest, ConvTranspose2dRejectsBadShapes) {
  Tensor x = eng().tensor({1, 4, 5, 6}), w = eng().tensor({4, 3, 2, 2}), b = eng().tensor({3});
  Tensor y = eng().tensor({1, 3, 10, 12});
  Recorder rec(eng());
  EXPECT_THROW(convTranspose2d(rec, x, eng().tensor({5, 3, 2, 2}), b, y), Error);     // Cin mismatch
  EXPECT_THROW(convTranspose2d(rec, x, eng().tensor({4, 3, 2, 3}), b, y), Error);     // non-square kernel
  EXPECT_THROW(convTranspose2d(rec, x, w, b, eng().tensor({1, 3, 10, 11})), Error);   // output size
  EXPECT_THROW(convTranspose2d(rec, x, w, eng().tensor({4}), y), Error);               // bias size
  EXPECT_THROW(convTranspose2d(rec, eng().tensor({4, 5, 6}), w, b, y), Error);         // rank
  EXPECT_EQ(rec.pending(), 0u);
}

}  // namespace
}  // namespace spar::test
