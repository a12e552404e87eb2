// conv2d (shaders/conv2d.comp via engine/ops/conv2d.cpp) against a float64 reference.
#include "engine/ops/conv2d.h"

#include <algorithm>
#include <cmath>

#include "tests/quantized_weights.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

struct ConvCase {
  int64_t N, Cin, H, W, Cout, KH, KW;
  int stride, padY, padX;
  bool bias;
  Activation act;
};

// Readable test names and failure messages.
std::string describe(const ConvCase& c) {
  return "N" + std::to_string(c.N) + "_Cin" + std::to_string(c.Cin) + "_" + std::to_string(c.H) + "x" +
         std::to_string(c.W) + "_Cout" + std::to_string(c.Cout) + "_k" + std::to_string(c.KH) + "x" +
         std::to_string(c.KW) + "_s" + std::to_string(c.stride) + "_pad" + std::to_string(c.padY) + "x" +
         std::to_string(c.padX) + (c.bias ? "_bias" : "") + "_act" + std::to_string(int(c.act));
}
void PrintTo(const ConvCase& c, std::ostream* os) { *os << describe(c); }

std::vector<double> conv2dRef(const ConvCase& c, const std::vector<float>& x, const std::vector<float>& w,
                              const std::vector<float>& b) {
  const int64_t Ho = (c.H + 2 * c.padY - c.KH) / c.stride + 1, Wo = (c.W + 2 * c.padX - c.KW) / c.stride + 1;
  std::vector<double> y(c.N * c.Cout * Ho * Wo);
  for (int64_t n = 0; n < c.N; ++n)
    for (int64_t co = 0; co < c.Cout; ++co)
      for (int64_t oy = 0; oy < Ho; ++oy)
        for (int64_t ox = 0; ox < Wo; ++ox) {
          double s = b.empty() ? 0.0 : b[co];
          for (int64_t ci = 0; ci < c.Cin; ++ci)
            for (int64_t ky = 0; ky < c.KH; ++ky)
              for (int64_t kx = 0; kx < c.KW; ++kx) {
                const int64_t iy = oy * c.stride - c.padY + ky, ix = ox * c.stride - c.padX + kx;
                if (iy < 0 || iy >= c.H || ix < 0 || ix >= c.W) continue;
                s += double(x[((n * c.Cin + ci) * c.H + iy) * c.W + ix]) * w[((co * c.Cin + ci) * c.KH + ky) * c.KW + kx];
              }
          y[((n * c.Cout + co) * Ho + oy) * Wo + ox] = activateRef(s, c.act);
        }
  return y;
}

Shape outShape(const ConvCase& c) {
  return {c.N, c.Cout, conv2dOutputSize(c.H, c.KH, c.stride, c.padY), conv2dOutputSize(c.W, c.KW, c.stride, c.padX)};
}

Conv2dParams paramsOf(const ConvCase& c) {
  Conv2dParams p;
  p.stride = c.stride;
  p.padY = c.padY;
  p.padX = c.padX;
  p.act = c.act;
  return p;
}

// Runs one case on x, w, b and checks it against the reference.
void runCase(Engine& eng, const ConvCase& c, const std::vector<float>& x, const std::vector<float>& w,
             const std::vector<float>& b, double maxNmse, double maxAbs, const std::string& what) {
  Tensor tx = eng.fromFloats({c.N, c.Cin, c.H, c.W}, x), tw = eng.fromFloats({c.Cout, c.Cin, c.KH, c.KW}, w);
  Tensor tb = c.bias ? eng.fromFloats({c.Cout}, b) : Tensor();
  GuardedOutput y(eng, outShape(c));
  Recorder rec(eng);
  conv2d(rec, tx, tw, tb, y.tensor(), paramsOf(c));
  rec.run();
  expectClose(y.read(), conv2dRef(c, x, w, c.bias ? b : std::vector<float>{}), maxNmse, maxAbs, what);
  y.expectAllWritten();
}

class Conv2dTest : public EngineTest, public ::testing::WithParamInterface<ConvCase> {};

TEST_P(Conv2dTest, MatchesFloat64Reference) {
  const auto c = GetParam();
  auto x = randomUniform(c.N * c.Cin * c.H * c.W, -1, 1, 1);
  auto w = randomUniform(c.Cout * c.Cin * c.KH * c.KW, -1, 1, 2);
  auto b = randomUniform(c.Cout, -1, 1, 3);
  runCase(eng(), c, x, w, b, 1e-8, 1e-4, "conv2d");
}

// Odd channel counts and sizes hit every tail; W % 4 == 0 cases take the RGBA input path,
// Cin * kh * kw % 4 == 0 cases the RGBA weight path.
INSTANTIATE_TEST_SUITE_P(
    Shapes, Conv2dTest,
    ::testing::Values(
        ConvCase{1, 7, 13, 13, 61, 3, 3, 1, 1, 1, true, Activation::None},        // 3x3 pad 1, R texels
        ConvCase{2, 61, 13, 7, 7, 3, 3, 2, 1, 1, false, Activation::None},        // stride 2
        ConvCase{1, 64, 16, 16, 64, 3, 3, 1, 1, 1, true, Activation::None},       // RGBA input and weights
        ConvCase{2, 16, 20, 24, 33, 3, 3, 2, 1, 1, true, Activation::None},       // RGBA, stride 2
        ConvCase{1, 3, 61, 61, 16, 3, 3, 2, 0, 0, true, Activation::Silu},        // RGB input, pad 0
        ConvCase{1, 64, 16, 16, 61, 1, 1, 1, 0, 0, true, Activation::None},       // 1x1, RGBA
        ConvCase{2, 9, 7, 9, 13, 1, 1, 1, 0, 0, true, Activation::None},          // 1x1, 63 pixels: not whole texels
        ConvCase{2, 13, 61, 17, 5, 1, 1, 2, 0, 0, false, Activation::Gelu},       // 1x1 stride 2
        ConvCase{1, 12, 8, 12, 7, 1, 1, 1, 1, 1, true, Activation::None},         // 1x1 with padding
        ConvCase{1, 8, 12, 32, 20, 3, 3, 1, 1, 1, true, Activation::QuickGelu},   // RGBA, shift 3
        ConvCase{1, 8, 12, 32, 9, 3, 3, 2, 0, 0, true, Activation::Sigmoid},      // RGBA, shift 0, stride 2
        ConvCase{1, 16, 9, 12, 17, 3, 3, 1, 1, 1, true, Activation::Relu},       // RGBA weights, R input
        ConvCase{3, 4, 9, 8, 9, 5, 5, 1, 2, 2, true, Activation::None},           // 5x5 pad 2
        ConvCase{1, 5, 11, 10, 6, 2, 2, 2, 0, 0, false, Activation::None},        // 2x2 stride 2
        ConvCase{1, 6, 13, 16, 11, 3, 1, 1, 1, 0, true, Activation::None},        // 3x1, padY only
        ConvCase{1, 6, 7, 7, 3, 7, 7, 1, 0, 0, true, Activation::None},           // kernel = image, 1x1 out
        ConvCase{1, 128, 9, 11, 5, 3, 3, 1, 1, 1, false, Activation::None},       // K = 1152
        // The flat walk over output blocks (CPU tiles) wraps across block rows: partial last
        // column block (36 = 4 x 8 + 4) and row block (5 rows); vec4 stores (Wo % 4 == 0).
        ConvCase{2, 8, 5, 36, 9, 3, 3, 1, 1, 1, true, Activation::Gelu},
        ConvCase{1, 4, 7, 7, 5, 3, 3, 1, 1, 1, true, Activation::None},           // fewer blocks than lanes
        ConvCase{3, 16, 21, 12, 1, 1, 1, 1, 0, 0, true, Activation::Gelu},       // CV-DRP's head: Cout 1
        ConvCase{2, 12, 11, 20, 3, 3, 3, 1, 1, 1, true, Activation::Gelu}),      // Cout 3 < channel block
    [](const ::testing::TestParamInfo<ConvCase>& info) { return describe(info.param); });

// 64 -> 64 channels, 3x3, at a realistic resolution (the bench shape, smaller).
TEST_F(EngineTest, Conv2d3x3At64x64) {
  const ConvCase c{1, 64, 64, 64, 64, 3, 3, 1, 1, 1, true, Activation::None};
  auto x = randomNormal(c.N * c.Cin * c.H * c.W, 0, 1, 4);
  auto w = randomNormal(c.Cout * c.Cin * 9, 0, 0.05f, 5);
  auto b = randomNormal(c.Cout, 0, 0.1f, 6);
  runCase(eng(), c, x, w, b, 1e-8, 1e-4, "64->64 3x3");
}

// CV-DRP's first decoder conv at its full-size shape: 128 channels on a 32x32 plane, 4 images
// (a small plane with many channels: the flat walk fills the lanes).
TEST_F(EngineTest, Conv2dDecoderShape128At32x32) {
  const ConvCase c{4, 128, 32, 32, 128, 3, 3, 1, 1, 1, true, Activation::Gelu};
  auto x = randomNormal(c.N * c.Cin * c.H * c.W, 0, 1, 21);
  auto w = randomNormal(c.Cout * c.Cin * 9, 0, 0.03f, 22);
  auto b = randomNormal(c.Cout, 0, 0.1f, 23);
  runCase(eng(), c, x, w, b, 1e-8, 1e-4, "128->128 3x3 at 32x32, 4 images");
}

// The GPU tiles (2-D workgroups 16 x 8, 4 channels x 1 row x 4 columns, no flat walk) stay
// correct on this CPU device: the path a discrete GPU takes is tested here too.
TEST_F(EngineTest, Conv2dGpuTilesMatchReference) {
  ScopedEnv tiles("SPAR_CONV_TILES", "4,1,4,16,8");
  for (const ConvCase& c : {ConvCase{2, 8, 5, 36, 9, 3, 3, 1, 1, 1, true, Activation::Gelu},
                            ConvCase{1, 7, 13, 13, 61, 3, 3, 1, 1, 1, true, Activation::None},
                            ConvCase{2, 16, 20, 24, 33, 3, 3, 2, 1, 1, true, Activation::None},
                            ConvCase{3, 16, 21, 12, 1, 1, 1, 1, 0, 0, true, Activation::Gelu}}) {
    auto x = randomUniform(c.N * c.Cin * c.H * c.W, -1, 1, 24);
    auto w = randomUniform(c.Cout * c.Cin * c.KH * c.KW, -1, 1, 25);
    auto b = randomUniform(c.Cout, -1, 1, 26);
    runCase(eng(), c, x, w, b, 1e-8, 1e-4, "GPU tiles " + describe(c));
  }
}

// An output view starting off a 4-element boundary cannot take the vec4 stores and falls
// back to float stores; on a boundary it takes them. Both match, and nothing before the
// view (or after the buffer's guard) is written.
TEST_F(EngineTest, Conv2dOutputAtAnyOffset) {
  const ConvCase c{2, 8, 9, 16, 21, 3, 3, 1, 1, 1, true, Activation::None};
  auto x = randomUniform(c.N * c.Cin * c.H * c.W, -1, 1, 27), w = randomUniform(c.Cout * c.Cin * 9, -1, 1, 28);
  auto b = randomUniform(c.Cout, -1, 1, 29);
  const auto want = conv2dRef(c, x, w, b);
  Tensor tx = eng().fromFloats({c.N, c.Cin, c.H, c.W}, x), tw = eng().fromFloats({c.Cout, c.Cin, 3, 3}, w);
  Tensor tb = eng().fromFloats({c.Cout}, b);
  for (int64_t off : {0, 1, 2, 3, 4}) {
    const int64_t n = shapeNumel(outShape(c));
    GuardedOutput y(eng(), {off + n});
    Recorder rec(eng());
    conv2d(rec, tx, tw, tb, y.tensor().view(off, outShape(c)), paramsOf(c));
    rec.run();
    const std::vector<float> all = y.read();
    for (int64_t i = 0; i < off; ++i) EXPECT_TRUE(std::isnan(all[size_t(i)])) << "wrote before the view, offset " << off;
    expectClose(std::vector<float>(all.begin() + off, all.end()), want, 1e-8, 1e-4, "offset " + std::to_string(off));
  }
}

// A black image gives exactly the bias: no stray products (or padding reads) reach the sum.
TEST_F(EngineTest, Conv2dBlackImageGivesBias) {
  const ConvCase c{2, 13, 17, 16, 19, 3, 3, 1, 1, 1, true, Activation::None};
  std::vector<float> x(c.N * c.Cin * c.H * c.W, 0.0f);
  auto w = randomUniform(c.Cout * c.Cin * 9, -1, 1, 7), b = randomUniform(c.Cout, -1, 1, 8);
  runCase(eng(), c, x, w, b, 0.0, 0.0, "black image");
}

// A white image with dyadic weights (multiples of 1/8): every partial sum is exact in fp32,
// so the result must equal the reference exactly, borders (fewer taps) included.
TEST_F(EngineTest, Conv2dWhiteImageDyadicWeightsIsExact) {
  for (const ConvCase& c : {ConvCase{1, 13, 17, 16, 19, 3, 3, 1, 1, 1, true, Activation::None},
                            ConvCase{2, 8, 21, 24, 7, 3, 3, 2, 1, 1, true, Activation::None},
                            ConvCase{1, 16, 9, 9, 5, 1, 1, 1, 0, 0, false, Activation::None}}) {
    std::vector<float> x(c.N * c.Cin * c.H * c.W, 1.0f);
    auto w = randomUniform(c.Cout * c.Cin * c.KH * c.KW, -2, 2, 9), b = randomUniform(c.Cout, -2, 2, 10);
    for (auto& v : w) v = std::round(v * 8) / 8;
    for (auto& v : b) v = std::round(v * 8) / 8;
    runCase(eng(), c, x, w, b, 0.0, 0.0, "white image, dyadic");
  }
}

// Inputs, weights and bias at offsets that are not texel-aligned (views into bigger
// buffers) are bound from an aligned start; the result is unchanged.
TEST_F(EngineTest, Conv2dTensorsAtUnalignedOffsets) {
  const ConvCase c{2, 8, 12, 16, 10, 3, 3, 1, 1, 1, true, Activation::None};
  const int64_t nx = c.N * c.Cin * c.H * c.W, nw = c.Cout * c.Cin * 9;
  auto x = randomUniform(nx, -1, 1, 11), w = randomUniform(nw, -1, 1, 12), b = randomUniform(c.Cout, -1, 1, 13);
  std::vector<float> all(3 + nx + 1 + nw + 2 + c.Cout);
  std::copy(x.begin(), x.end(), all.begin() + 3);
  std::copy(w.begin(), w.end(), all.begin() + 3 + nx + 1);
  std::copy(b.begin(), b.end(), all.begin() + 3 + nx + 1 + nw + 2);
  Tensor t = eng().fromFloats({int64_t(all.size())}, all);
  Tensor tx = t.view(3, {c.N, c.Cin, c.H, c.W}), tw = t.view(3 + nx + 1, {c.Cout, c.Cin, 3, 3});
  Tensor tb = t.view(3 + nx + 1 + nw + 2, {c.Cout});
  GuardedOutput y(eng(), outShape(c));
  Recorder rec(eng());
  conv2d(rec, tx, tw, tb, y.tensor(), paramsOf(c));
  rec.run();
  expectClose(y.read(), conv2dRef(c, x, w, b), 1e-8, 1e-4, "unaligned views");
  y.expectAllWritten();
}

// Outputs beyond one storage binding are written in chunks of (image, channel block)
// units; the binding limit is lowered so the split happens at a small size. A 3x3 and a 1x1
// over whole texels of pixels (the GPU family's POINTWISE GEMM, each chunk's image read as
// RGBA texels from its own start).
TEST_F(EngineTest, Conv2dOutputSplitIntoChunks) {
  for (const ConvCase c : {ConvCase{3, 5, 11, 13, 37, 3, 3, 1, 1, 1, true, Activation::None},
                           ConvCase{3, 5, 12, 12, 37, 1, 1, 1, 0, 0, true, Activation::None}}) {
    const int64_t taps = c.KH * c.KW;
    auto x = randomUniform(c.N * c.Cin * c.H * c.W, -1, 1, 14), w = randomUniform(c.Cout * c.Cin * taps, -1, 1, 15);
    auto b = randomUniform(c.Cout, -1, 1, 16);
    Tensor tx = eng().fromFloats({c.N, c.Cin, c.H, c.W}, x), tw = eng().fromFloats({c.Cout, c.Cin, c.KH, c.KW}, w);
    Tensor tb = eng().fromFloats({c.Cout}, b);
    GuardedOutput y(eng(), outShape(c));
    const int64_t block = chooseConvTiles(eng().caps(), eng().options().tuning, c.KH, c.KW).channels;
    const int64_t units = c.N * ((c.Cout + block - 1) / block);
    // Room for two units (plus alignment slack) per binding; where inputs are storage buffers
    // (plan().storageInputs) the weight is bound within the same range, so room for it too.
    const bool inputsInRange = eng().plan().storageInputs;
    uint64_t room = uint64_t(2 * block * c.H * c.W + 64);
    if (inputsInRange) room = std::max<uint64_t>(room, uint64_t(c.Cout * c.Cin * taps + 64));
    ScopedBindingRange lowered(eng(), room * 4);
    Recorder rec(eng());
    conv2d(rec, tx, tw, tb, y.tensor(), paramsOf(c));
    if (eng().plan().conv == KernelFamily::CpuBlocks && !inputsInRange) EXPECT_EQ(rec.pending(), size_t((units + 1) / 2));
    else EXPECT_GT(rec.pending(), size_t(1));  // the GPU family's units are blocks of its own size
    rec.run();
    lowered.restore();
    expectClose(y.read(), conv2dRef(c, x, w, b), 1e-8, 1e-4, "chunked " + std::to_string(c.KH) + "x" + std::to_string(c.KW));
    y.expectAllWritten();
  }
}

// ---- Quantized kernels (engine/tensor.h DType::Q8 / Q4: the matrix [Cout, Cin*kh*kw]),
// against float64 of the dequantized weights: the kernel adds no error beyond fp32
// accumulation. Odd Cout, odd image sizes; a 3x3 with bias (K = 288: nine blocks), a 1x1 at
// stride 2 without bias (the placeholder binding) and vec4 stores; the stiff blocks.
void expectQuantizedConv(Engine& eng, const ConvCase& c, const std::vector<float>& w, int bits, const std::string& what) {
  const int64_t K = c.Cin * c.KH * c.KW;
  const auto x = randomUniform(c.N * c.Cin * c.H * c.W, -1, 1, 31);
  const auto b = c.bias ? randomUniform(c.Cout, -1, 1, 32) : std::vector<float>{};
  const QuantizedMatrix q = quantizeReference(w, c.Cout, K, bits);
  Tensor tx = eng.fromFloats({c.N, c.Cin, c.H, c.W}, x), tw = quantizedTensor(eng, q, c.Cout, K, bits);
  Tensor tb = c.bias ? eng.fromFloats({c.Cout}, b) : Tensor();
  GuardedOutput y(eng, outShape(c));
  Conv2dParams p = paramsOf(c);
  p.kernelH = int(c.KH);
  p.kernelW = int(c.KW);
  Recorder rec(eng);
  conv2d(rec, tx, tw, tb, y.tensor(), p);
  rec.run();
  const auto ref = conv2dRef(c, x, q.values, b);
  // fp32 accumulation's own bound: K * 2^-24 * sum |w x| of an output (Higham's gamma_K); with
  // an outlier of 1e4 every later product is added at that magnitude's spacing
  auto absOf = [](std::vector<float> v) {
    for (float& e : v) e = std::abs(e);
    return v;
  };
  ConvCase plain = c;
  plain.act = Activation::None;
  double peak = 0, products = 0;
  for (double v : ref) peak = std::max(peak, std::abs(v));
  for (double v : conv2dRef(plain, absOf(x), absOf(q.values), {})) products = std::max(products, v);
  const double accumulation = double(K) * std::ldexp(1.0, -24) * products;
  expectClose(y.read(), ref, 1e-10 * std::max<int64_t>(1, K / 16), std::max(1e-6 * std::max(1.0, peak), accumulation), what);
  y.expectAllWritten();
}

TEST_F(EngineTest, Conv2dQuantizedMatchesFloat64OfDequantized) {
  const ConvCase c3{1, 32, 11, 9, 13, 3, 3, 1, 1, 1, true, Activation::None};
  expectQuantizedConv(eng(), c3, randomUniform(13 * 32 * 9, -1, 1, 33), 8, "q8 3x3");
  const ConvCase c1{2, 64, 10, 16, 7, 1, 1, 2, 0, 0, false, Activation::None};  // Wo 8: vec4 stores
  expectQuantizedConv(eng(), c1, randomUniform(7 * 64, -1, 1, 34), 4, "q4 1x1 stride 2");
  const ConvCase pointwise{2, 64, 10, 16, 7, 1, 1, 1, 0, 0, true, Activation::None};  // the GPU family's POINTWISE
  expectQuantizedConv(eng(), pointwise, randomUniform(7 * 64, -1, 1, 36), 8, "q8 1x1");
  // the stiff blocks: one row of 9 blocks per output channel, the first three stiff
  expectQuantizedConv(eng(), c3, stiffQuantizedRows(13, 32 * 9, 35), 4, "q4 3x3 stiff");
}

TEST_F(EngineTest, Conv2dQuantizedRefusesWhatItCannotRead) {
  Tensor x = eng().tensor({1, 32, 8, 8}), y = eng().tensor({1, 6, 8, 8});
  Tensor w = eng().tensor({6, 32 * 9}, DType::Q8);
  Recorder rec(eng());
  Conv2dParams p;
  p.padY = p.padX = 1;
  EXPECT_THROW(conv2d(rec, x, w, Tensor(), y, p), Error);  // no kernel size
  p.kernelH = p.kernelW = 3;
  EXPECT_NO_THROW(conv2d(rec, x, w, Tensor(), y, p));
  p.kernelW = 1;
  EXPECT_THROW(conv2d(rec, x, w, Tensor(), y, p), Error);  // K is not Cin * kh * kw
  EXPECT_EQ(rec.pending(), 1u);
  rec.run();
}

TEST_F(EngineTest, Conv2dRejectsBadShapes) {
  Tensor x = eng().tensor({1, 4, 8, 8}), w = eng().tensor({6, 4, 3, 3}), b = eng().tensor({6});
  Tensor y = eng().tensor({1, 6, 8, 8});
  Recorder rec(eng());
  Conv2dParams pad1;
  pad1.padY = pad1.padX = 1;
  EXPECT_NO_THROW(conv2d(rec, x, w, b, y, pad1));
  const size_t recorded = rec.pending();  // one dispatch, or im2col's two (where the plan has the lanes GEMM)
  EXPECT_GE(recorded, 1u);
  EXPECT_THROW(conv2d(rec, x, w, b, y), Error);  // no padding: output would be 6x6
  EXPECT_THROW(conv2d(rec, x, eng().tensor({6, 5, 3, 3}), b, y, pad1), Error);            // Cin mismatch
  EXPECT_THROW(conv2d(rec, x, w, eng().tensor({5}), y, pad1), Error);                     // bias size
  EXPECT_THROW(conv2d(rec, x, w, b, eng().tensor({1, 7, 8, 8}), pad1), Error);            // Cout mismatch
  EXPECT_THROW(conv2d(rec, eng().tensor({4, 8, 8}), w, b, y, pad1), Error);               // rank
  EXPECT_THROW(conv2d(rec, x, eng().tensor({6, 4, 9}), b, y, pad1), Error);               // weight rank
  EXPECT_THROW(conv2d(rec, eng().tensor({1, 4, 2, 2}), w, b, eng().tensor({1, 6, 0, 0})), Error);  // kernel > input
  Conv2dParams stride0;
  stride0.stride = 0;
  EXPECT_THROW(conv2d(rec, x, w, b, y, stride0), Error);
  if (eng().caps().supportsFp16Storage()) {
    EXPECT_THROW(conv2d(rec, eng().tensor({1, 4, 8, 8}, DType::F16), w, b, y, pad1), Error);  // f32 only
  }
  EXPECT_EQ(rec.pending(), recorded);  // the refused calls recorded nothing
  rec.run();
}

// SwiftShader's convolutions (KernelPlan::gemmLanesSplitK): im2col (shaders/im2col.comp) and the
// lanes GEMM with the bias per row (gemmLanesRowBias), forced on this device through texel and
// storage inputs, constants written into the modules: padding, stride 2, 1x1, 5x5, K not a
// multiple of 4 or of the subgroup, every activation, and a plane in two bands of output rows
// (64 channels x 3x3 at 128 columns: 14 rows a band of the 4 MiB of patches).
TEST_F(EngineTest, Conv2dIm2colLanesGemmMatchesFloat64) {
  const DeviceCaps& caps = eng().caps();
  withLanesKernelsForced(eng(), [&](const std::string& inputs) {
    for (const ConvCase& c : {ConvCase{1, 7, 13, 13, 61, 3, 3, 1, 1, 1, true, Activation::None},
                              ConvCase{2, 61, 13, 7, 7, 3, 3, 2, 1, 1, false, Activation::Gelu},
                              ConvCase{1, 3, 61, 61, 16, 3, 3, 2, 0, 0, true, Activation::Silu},
                              ConvCase{2, 13, 61, 17, 5, 1, 1, 2, 0, 0, false, Activation::QuickGelu},
                              ConvCase{3, 4, 9, 8, 9, 5, 5, 1, 2, 2, true, Activation::Sigmoid},
                              ConvCase{3, 16, 21, 12, 1, 1, 1, 1, 0, 0, true, Activation::Relu},
                              ConvCase{1, 64, 16, 128, 5, 3, 3, 1, 1, 1, true, Activation::Gelu}}) {
      // texel inputs: only where an image fits one texel binding (SwiftShader's hold 65536)
      if (inputs == "texel" && uint64_t(c.Cin * c.H * c.W) > caps.maxTexelBufferElements) continue;
      auto x = randomUniform(c.N * c.Cin * c.H * c.W, -1, 1, 31);
      auto w = randomUniform(c.Cout * c.Cin * c.KH * c.KW, -1, 1, 32);
      auto b = randomUniform(c.Cout, -1, 1, 33);
      Tensor tx = eng().fromFloats({c.N, c.Cin, c.H, c.W}, x), tw = eng().fromFloats({c.Cout, c.Cin, c.KH, c.KW}, w);
      Tensor tb = c.bias ? eng().fromFloats({c.Cout}, b) : Tensor();
      GuardedOutput y(eng(), outShape(c));
      Recorder rec(eng());
      conv2d(rec, tx, tw, tb, y.tensor(), paramsOf(c));
      const int64_t Ho = outShape(c)[2], bands = c.Cin == 64 ? 2 : 1;
      EXPECT_EQ(rec.pending(), size_t(2 * c.N * bands)) << describe(c);  // im2col and the GEMM per band
      rec.run();
      expectClose(y.read(), conv2dRef(c, x, w, c.bias ? b : std::vector<float>{}), 1e-8, 1e-4,
                  "im2col, " + inputs + " inputs, " + describe(c) + ", " + std::to_string(Ho) + " rows");
      y.expectAllWritten();
    }
  });
}

}  // namespace
}  // namespace spar::test
