// The checks of `spar selftest` (selftest_checks.h). Shapes are odd (no multiple of a tile or a
// vector width), one linear crosses a texel binding of 65536 texels, and the stiff ones are the
// engineering notes' cases: LayerNorm rows of mean 1e4 and variance 1e-6, softmax logits of
// +-1e4, GELU at +-1e4 and near 0, attention with logits of about 1e3. Thresholds are those the
// op tests use (tests/test_<op>.cpp).
#include "selftest/selftest_checks.h"

#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>

#include "engine/half.h"
#include "engine/ops/attention.h"
#include "engine/ops/conv2d.h"
#include "engine/ops/linear.h"
#include "engine/ops/norm.h"
#include "engine/ops/reduce_channels.h"
#include "engine/ops/unary.h"
#include "engine/uniform_floats.h"
#include "model/quantized_matrices.h"

namespace spar::selftest {
namespace {

std::vector<float> uniform(size_t n, float lo, float hi, uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<float> v(n);
  for (float& x : v) x = uniformFloat(rng, lo, hi);
  return v;
}

double gelu(double x) { return 0.5 * x * std::erfc(-x / std::sqrt(2.0)); }

// Runs `work` (recording into a fresh recorder, returning the output tensor), times it and
// compares the output with `want`.
SelftestCheck check(Engine& engine, std::string name, std::string family, double maxNmse, double maxAbs,
                    const std::function<Tensor(Recorder&)>& work, const std::function<std::vector<double>()>& want) {
  SelftestCheck c{std::move(name), std::move(family), 0, 0, maxNmse, maxAbs};
  try {
    const auto t0 = std::chrono::steady_clock::now();
    Recorder rec(engine);
    const Tensor out = work(rec);
    rec.run();
    c.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    measureAgainst(c, engine.download(out), want());
  } catch (const std::exception& e) {
    c.error = e.what();
  }
  return c;
}

SelftestCheck linearCheck(Engine& engine, int64_t M, int64_t N, int64_t K, bool gelu_, uint32_t seed) {
  const auto x = uniform(size_t(M * K), -1, 1, seed), w = uniform(size_t(N * K), -0.1f, 0.1f, seed + 1),
             b = uniform(size_t(N), -1, 1, seed + 2);
  const std::string name = "linear " + std::to_string(M) + "x" + std::to_string(N) + "x" + std::to_string(K) + " +bias" +
                           (gelu_ ? " GELU" : "");
  return check(
      engine, name, familyName(engine.plan().gemm), 1e-9, 1e-4,
      [&](Recorder& rec) {
        Tensor tx = engine.fromFloats({M, K}, x), tw = engine.fromFloats({N, K}, w), tb = engine.fromFloats({N}, b);
        Tensor y = engine.tensor({M, N});
        linear(rec, tx, tw, tb, y, gelu_ ? Activation::Gelu : Activation::None);
        return y;
      },
      [&] {
        std::vector<double> y(size_t(M * N));
        for (int64_t m = 0; m < M; ++m)
          for (int64_t n = 0; n < N; ++n) {
            double s = b[size_t(n)];
            for (int64_t k = 0; k < K; ++k) s += double(x[size_t(m * K + k)]) * double(w[size_t(n * K + k)]);
            y[size_t(m * N + n)] = gelu_ ? gelu(s) : s;
          }
        return y;
      });
}

// float64 x W^T of x [M, K] and the weights w(n, k) the kernel reads.
std::vector<double> productRef(const std::vector<float>& x, int64_t M, int64_t N, int64_t K,
                               const std::function<double(int64_t, int64_t)>& w) {
  std::vector<double> y(size_t(M * N));
  for (int64_t m = 0; m < M; ++m)
    for (int64_t n = 0; n < N; ++n) {
      double s = 0;
      for (int64_t k = 0; k < K; ++k) s += double(x[size_t(m * K + k)]) * w(n, k);
      y[size_t(m * N + n)] = s;
    }
  return y;
}

// fp16 weight matrices (the fp16 precision): the plan's fp16 GEMM family (fp16 arithmetic or
// cooperative matrices where the device has them), against float64 of the fp16-rounded weights.
SelftestCheck linearF16Check(Engine& engine) {
  const int64_t M = 67, N = 130, K = 96;
  const auto x = uniform(size_t(M * K), -1, 1, 81), w = uniform(size_t(N * K), -0.1f, 0.1f, 82);
  std::vector<float> wRounded;
  return check(
      engine, "linear 67x130x96, fp16 weights", familyName(engine.plan().gemmF16), 1e-6, 2e-3,
      [&](Recorder& rec) {
        Tensor tx = engine.fromFloats({M, K}, x), tw = engine.fromFloats({N, K}, w, DType::F16);
        wRounded = engine.download(tw);
        Tensor y = engine.tensor({M, N});
        linear(rec, tx, tw, Tensor(), y);
        return y;
      },
      [&] { return productRef(x, M, N, K, [&](int64_t n, int64_t k) { return double(wRounded[size_t(n * K + k)]); }); });
}

// Element (n, k) of the quantized rows [N, K] (engine/tensor.h DType::Q8 / Q4): code * scale,
// as the kernels compute it.
std::function<double(int64_t, int64_t)> dequantized(const std::vector<uint8_t>& rows, int64_t K, DType q) {
  const int bits = q == DType::Q8 ? 8 : 4;
  const size_t codeBytes = size_t(K) * size_t(bits) / 8, rowBytes = codeBytes + size_t(K) / 8;
  return [&rows, codeBytes, rowBytes, bits](int64_t n, int64_t k) {
    const uint8_t* row = rows.data() + size_t(n) * rowBytes;
    float scale;
    std::memcpy(&scale, row + codeBytes + size_t(k / 32) * 4, 4);
    const int code = bits == 8 ? int(int8_t(row[k])) : int((row[k / 2] >> (4 * (k & 1))) & 0xF) - 8;
    return double(float(code) * scale);
  };
}

// Quantized weight matrices (q8 / q4: the GEMM dequantizes them, converter/FORMAT.md), against
// float64 of the dequantized weights, with the stiff blocks: row 0 has an outlier of 1e4 among
// values of 0.1, row 1 an all-zero block, row 2 a block of float's smallest normal values.
SelftestCheck linearQuantizedCheck(Engine& engine, DType q) {
  const int64_t M = 67, N = 130, K = 96;
  const auto x = uniform(size_t(M * K), -1, 1, 91);
  auto w = uniform(size_t(N * K), -0.1f, 0.1f, 92);
  w[7] = 1e4f;
  for (int64_t k = 32; k < 64; ++k) w[size_t(K + k)] = 0.0f;
  for (int64_t k = 64; k < 96; ++k) w[size_t(2 * K + k)] = float(k % 3) * std::numeric_limits<float>::min();
  const std::vector<uint8_t> rows = quantizeRows(w, N, K, q);
  const auto exact = dequantized(rows, K, q);
  // Cooperative matrices stage x and the dequantized weights as fp16 (shaders/gemm_coopmat.comp):
  // the reference rounds both, and the bounds are the fp16 check's (how the driver rounds to fp16
  // is its own: one ulp of an input of 1e4's row is 8), else fp32 accumulation's.
  const bool viaFp16 = engine.plan().quantizedGemm() == KernelFamily::CoopMat;
  auto half = [](double v) { return double(halfToFloat(floatToHalf(float(v)))); };
  std::vector<float> xRef = x;
  if (viaFp16)
    for (float& v : xRef) v = float(half(v));
  const std::function<double(int64_t, int64_t)> value = [&](int64_t n, int64_t k) {
    return viaFp16 ? half(exact(n, k)) : exact(n, k);
  };
  return check(
      engine, std::string("linear 67x130x96, ") + dtypeName(q) + " weights, stiff blocks",
      // max abs: 1e-6 of the outputs' scale, 1e4 in row 0 (fp32 accumulation; measured 3-4e-3)
      std::string(familyName(engine.plan().quantizedGemm())) + " (dequantizing)", viaFp16 ? 1e-6 : 1e-9,
      viaFp16 ? 16.0 : 1e-2,
      [&](Recorder& rec) {
        Tensor tx = engine.fromFloats({M, K}, x), tw = engine.tensor({N, K}, q);
        engine.write(tw, rows.data(), rows.size());
        Tensor y = engine.tensor({M, N});
        linear(rec, tx, tw, Tensor(), y);
        return y;
      },
      [&] { return productRef(xRef, M, N, K, value); });
}

SelftestCheck attentionCheck(Engine& engine) {
  const int64_t N = 37, heads = 3, dh = 64, C = heads * dh;
  // q scaled so that logits reach about 1e3: one key dominates each row.
  const auto q = uniform(size_t(N * C), -4, 4, 31), k = uniform(size_t(N * C), -4, 4, 32), v = uniform(size_t(N * C), -1, 1, 33);
  return check(
      engine, "attention 3 heads x 37 tokens x 64, logits ~1e3", familyName(engine.plan().attention), 1e-9, 1e-4,
      [&](Recorder& rec) {
        Tensor tq = engine.fromFloats({N, C}, q), tk = engine.fromFloats({N, C}, k), tv = engine.fromFloats({N, C}, v);
        Tensor out = engine.tensor({N, C});
        attention(rec, {tq, 0}, {tk, 0}, {tv, 0}, {out, 0}, int(heads), int(dh));
        return out;
      },
      [&] {
        std::vector<double> out(size_t(N * C));
        const double scale = 1.0 / std::sqrt(double(dh));
        for (int64_t h = 0; h < heads; ++h)
          for (int64_t i = 0; i < N; ++i) {
            std::vector<double> logit(static_cast<size_t>(N));
            double top = -INFINITY;
            for (int64_t j = 0; j < N; ++j) {
              double s = 0;
              for (int64_t d = 0; d < dh; ++d) s += double(q[size_t(i * C + h * dh + d)]) * double(k[size_t(j * C + h * dh + d)]);
              logit[size_t(j)] = s * scale;
              top = std::max(top, logit[size_t(j)]);
            }
            double sum = 0;
            for (double& l : logit) sum += (l = std::exp(l - top));
            for (int64_t d = 0; d < dh; ++d) {
              double acc = 0;
              for (int64_t j = 0; j < N; ++j) acc += logit[size_t(j)] * double(v[size_t(j * C + h * dh + d)]);
              out[size_t(i * C + h * dh + d)] = acc / sum;
            }
          }
        return out;
      });
}

SelftestCheck layerNormCheck(Engine& engine) {
  const int64_t rows = 37, d = 257;
  std::mt19937 rng(41);
  NormalFloats dist(1e4f, 1e-3f);
  std::vector<float> x(size_t(rows * d));
  for (float& v : x) v = dist(rng);
  const auto w = uniform(size_t(d), 0.5f, 1.5f, 42), b = uniform(size_t(d), -1, 1, 43);
  return check(
      engine, "layernorm 37x257, rows of mean 1e4 and variance 1e-6", "-", 1e-9, 1e-4,
      [&](Recorder& rec) {
        Tensor tx = engine.fromFloats({rows, d}, x), tw = engine.fromFloats({d}, w), tb = engine.fromFloats({d}, b);
        Tensor y = engine.tensor({rows, d});
        layerNorm(rec, tx, tw, tb, y, 1e-12f);
        return y;
      },
      [&] {
        std::vector<double> y(size_t(rows * d));
        for (int64_t r = 0; r < rows; ++r) {
          double mean = 0, var = 0;
          for (int64_t i = 0; i < d; ++i) mean += x[size_t(r * d + i)];
          mean /= double(d);
          for (int64_t i = 0; i < d; ++i) var += (x[size_t(r * d + i)] - mean) * (x[size_t(r * d + i)] - mean);
          var /= double(d);
          for (int64_t i = 0; i < d; ++i)
            y[size_t(r * d + i)] = (x[size_t(r * d + i)] - mean) / std::sqrt(var + 1e-12) * w[size_t(i)] + b[size_t(i)];
        }
        return y;
      });
}

SelftestCheck softmaxCheck(Engine& engine) {
  const int64_t rows = 33, n = 1001;
  auto x = uniform(size_t(rows * n), -1e4f, 1e4f, 51);
  return check(
      engine, "softmax 33x1001, logits of +-1e4", "-", 1e-9, 1e-6,
      [&](Recorder& rec) {
        Tensor tx = engine.fromFloats({rows, n}, x);
        Tensor y = engine.tensor({rows, n});
        softmax(rec, tx, y);
        return y;
      },
      [&] {
        std::vector<double> y(size_t(rows * n));
        for (int64_t r = 0; r < rows; ++r) {
          double top = -INFINITY, sum = 0;
          for (int64_t i = 0; i < n; ++i) top = std::max(top, double(x[size_t(r * n + i)]));
          for (int64_t i = 0; i < n; ++i) sum += std::exp(double(x[size_t(r * n + i)]) - top);
          for (int64_t i = 0; i < n; ++i) y[size_t(r * n + i)] = std::exp(double(x[size_t(r * n + i)]) - top) / sum;
        }
        return y;
      });
}

SelftestCheck geluCheck(Engine& engine) {
  std::vector<float> x = uniform(997, -6, 6, 61);
  for (float v : {1e4f, -1e4f, 0.0f, 1e-30f, -1e-30f, -20.0f}) x.push_back(v);
  const int64_t n = int64_t(x.size());
  return check(
      engine, "GELU of 1003 values, +-1e4 and near 0", "-", 1e-10, 2e-3,  // 2e-3: an ulp of 1e4 is 9.8e-4
      [&](Recorder& rec) {
        Tensor tx = engine.fromFloats({n}, x);
        Tensor y = engine.tensor({n});
        activate(rec, Activation::Gelu, tx, y);
        return y;
      },
      [&] {
        std::vector<double> y(x.size());
        for (size_t i = 0; i < x.size(); ++i) y[i] = gelu(x[i]);
        return y;
      });
}

// float64 of a 3x3 pad-1 convolution of x [Cin, H, W] with weights w(co, ci * 9 + ky * 3 + kx).
std::vector<double> conv3x3Ref(const std::vector<float>& x, int64_t Cin, int64_t H, int64_t W, int64_t Cout,
                               const std::function<double(int64_t, int64_t)>& w, const std::vector<float>& b) {
  std::vector<double> y(size_t(Cout * H * W));
  for (int64_t co = 0; co < Cout; ++co)
    for (int64_t oy = 0; oy < H; ++oy)
      for (int64_t ox = 0; ox < W; ++ox) {
        double s = b[size_t(co)];
        for (int64_t ci = 0; ci < Cin; ++ci)
          for (int64_t ky = 0; ky < 3; ++ky)
            for (int64_t kx = 0; kx < 3; ++kx) {
              const int64_t iy = oy + ky - 1, ix = ox + kx - 1;
              if (iy < 0 || iy >= H || ix < 0 || ix >= W) continue;
              s += double(x[size_t((ci * H + iy) * W + ix)]) * w(co, (ci * 3 + ky) * 3 + kx);
            }
        y[size_t((co * H + oy) * W + ox)] = s;
      }
  return y;
}

SelftestCheck conv2dCheck(Engine& engine) {
  const int64_t Cin = 5, H = 37, W = 29, Cout = 7, K = Cin * 9;
  const auto x = uniform(size_t(Cin * H * W), -1, 1, 71), w = uniform(size_t(Cout * K), -0.3f, 0.3f, 72),
             b = uniform(size_t(Cout), -1, 1, 73);
  return check(
      engine, "conv2d 3x3 pad 1, 5->7 channels at 37x29", familyName(engine.plan().conv), 1e-9, 1e-4,
      [&](Recorder& rec) {
        Tensor tx = engine.fromFloats({1, Cin, H, W}, x), tw = engine.fromFloats({Cout, Cin, 3, 3}, w),
               tb = engine.fromFloats({Cout}, b);
        Tensor y = engine.tensor({1, Cout, H, W});
        conv2d(rec, tx, tw, tb, y, {1, 1, 1, Activation::None});
        return y;
      },
      [&] { return conv3x3Ref(x, Cin, H, W, Cout, [&](int64_t co, int64_t k) { return double(w[size_t(co * K + k)]); }, b); });
}

// Quantized convolution kernels (q8 / q4: LSeg's, the matrix [Cout, Cin*9] dequantized by the
// plan's conv2d family), against float64 of the dequantized weights; channel 0 has an
// outlier of 1e4 among values of 0.1, channel 1 an all-zero block.
SelftestCheck conv2dQuantizedCheck(Engine& engine, DType q) {
  const int64_t Cin = 32, H = 11, W = 9, Cout = 13, K = Cin * 9;
  const auto x = uniform(size_t(Cin * H * W), -1, 1, 101), b = uniform(size_t(Cout), -1, 1, 103);
  auto w = uniform(size_t(Cout * K), -0.1f, 0.1f, 102);
  w[5] = 1e4f;
  for (int64_t k = 32; k < 64; ++k) w[size_t(K + k)] = 0.0f;
  const std::vector<uint8_t> rows = quantizeRows(w, Cout, K, q);
  return check(
      engine, std::string("conv2d 3x3 pad 1, 32->13 channels at 11x9, ") + dtypeName(q) + " weights",
      // max abs: fp32 accumulation's bound K * 2^-24 * sum |w x| with the outlier's product of up
      // to 1e4 in channel 0 (0.17; every later product is added at 1e4's spacing: measured 1.1e-2
      // with q8, 1.3e-2 with q4, on lavapipe)
      std::string(familyName(engine.plan().quantizedConv())) + " (dequantizing)", 1e-9, double(K) * std::ldexp(1.0, -24) * 1e4,
      [&](Recorder& rec) {
        Tensor tx = engine.fromFloats({1, Cin, H, W}, x), tw = engine.tensor({Cout, K}, q), tb = engine.fromFloats({Cout}, b);
        engine.write(tw, rows.data(), rows.size());
        Tensor y = engine.tensor({1, Cout, H, W});
        conv2d(rec, tx, tw, tb, y, {.stride = 1, .padY = 1, .padX = 1, .kernelH = 3, .kernelW = 3});
        return y;
      },
      [&] { return conv3x3Ref(x, Cin, H, W, Cout, dequantized(rows, K, q), b); });
}

}  // namespace

void measureAgainst(SelftestCheck& c, const std::vector<float>& got, const std::vector<double>& want) {
  double err = 0, ref = 0;
  for (size_t i = 0; i < want.size(); ++i) {
    if (!std::isfinite(got[i])) c.finite = false;
    const double d = double(got[i]) - want[i];
    err += d * d;
    ref += want[i] * want[i];
    c.maxAbs = std::max(c.maxAbs, std::abs(d));
  }
  c.nmse = ref > 0 ? err / ref : err;
}

std::vector<SelftestCheck> runSelftestChecks(Engine& engine) {
  std::vector<SelftestCheck> checks;
  checks.push_back(linearCheck(engine, 77, 150, 72, true, 11));
  // 768 x 518 weights are 397824 R texels: more than the 65536 Vulkan guarantees a texel binding.
  checks.push_back(linearCheck(engine, 130, 768, 518, false, 21));
  // fp16 weights where the device can read them (elsewhere the engine keeps weights fp32).
  if (engine.readsFp16Inputs()) checks.push_back(linearF16Check(engine));
  // Quantized weights: every device reads them (32-bit words).
  for (DType q : {DType::Q8, DType::Q4}) checks.push_back(linearQuantizedCheck(engine, q));
  checks.push_back(attentionCheck(engine));
  checks.push_back(layerNormCheck(engine));
  checks.push_back(softmaxCheck(engine));
  checks.push_back(geluCheck(engine));
  checks.push_back(conv2dCheck(engine));
  for (DType q : {DType::Q8, DType::Q4}) checks.push_back(conv2dQuantizedCheck(engine, q));
  return checks;
}

}  // namespace spar::selftest
