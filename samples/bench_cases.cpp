#include "samples/bench_cases.h"

#include <cmath>
#include <random>

#include "engine/ops/attention.h"
#include "engine/ops/conv2d.h"
#include "engine/ops/linear.h"
#include "engine/ops/norm.h"
#include "engine/ops/reduce_channels.h"

namespace spar::bench {
namespace {

std::vector<float> randomValues(size_t n, uint32_t seed, float scale = 1.0f) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> dist(-scale, scale);
  std::vector<float> v(n);
  for (auto& x : v) x = dist(rng);
  return v;
}

// Rows to check against the float64 reference: 64 spread over the output.
std::vector<int64_t> sampleRows(int64_t rows) {
  std::vector<int64_t> out;
  const int64_t n = std::min<int64_t>(rows, 64);
  for (int64_t i = 0; i < n; ++i) out.push_back(i * rows / n + (i * 7) % std::max<int64_t>(1, rows / n));
  return out;
}

struct NmseAccumulator {
  double num = 0, den = 0;
  void add(double got, double ref) {
    num += (got - ref) * (got - ref);
    den += ref * ref;
  }
  double value() const { return den > 0 ? num / den : num; }
};

void addGemm(std::vector<BenchCase>& cases, Engine& engine, int64_t M, int64_t K, int64_t N, DType storage) {
  auto x = std::make_shared<std::vector<float>>(randomValues(M * K, 1));
  auto w = std::make_shared<std::vector<float>>(randomValues(N * K, 2, 0.05f));
  Tensor tx = engine.fromFloats({M, K}, *x, storage), tw = engine.fromFloats({N, K}, *w, storage);
  Tensor ty = engine.tensor({M, N}, storage);
  BenchCase c;
  c.name = storage == DType::F16 ? "gemm_f16" : "gemm_f32";
  c.shape = std::to_string(M) + "x" + std::to_string(K) + "x" + std::to_string(N);
  c.flops = 2.0 * M * N * K;
  c.record = [=](Recorder& rec) { linear(rec, tx, tw, Tensor(), ty); };
  c.nmse = [=, &engine]() {
    auto y = engine.download(ty);
    NmseAccumulator acc;
    for (int64_t m : sampleRows(M))
      for (int64_t n = 0; n < N; ++n) {
        double s = 0;
        for (int64_t k = 0; k < K; ++k) s += double((*x)[m * K + k]) * (*w)[n * K + k];
        acc.add(y[m * N + n], s);
      }
    return acc.value();
  };
  cases.push_back(std::move(c));
}

void addAttention(std::vector<BenchCase>& cases, Engine& engine, int64_t N, int heads, int dh, DType storage) {
  const int64_t D = int64_t(heads) * dh;
  auto qkv = std::make_shared<std::vector<float>>(randomValues(N * 3 * D, 3, 1.5f));
  Tensor t = engine.fromFloats({N, 3 * D}, *qkv, storage);
  Tensor o = engine.tensor({N, D}, storage);
  BenchCase c;
  c.name = storage == DType::F16 ? "attention_f16" : "attention_f32";
  c.shape = std::to_string(heads) + "x" + std::to_string(dh) + " heads, " + std::to_string(N) + " tokens";
  c.flops = 4.0 * double(N) * N * dh * heads;
  c.record = [=](Recorder& rec) { attention(rec, {t, 0}, {t, D}, {t, 2 * D}, {o, 0}, heads, dh); };
  c.nmse = [=, &engine]() {
    auto out = engine.download(o);
    const auto& a = *qkv;
    NmseAccumulator acc;
    std::vector<double> s(N);
    const double scale = 1.0 / std::sqrt(double(dh));
    for (int64_t i : sampleRows(N))
      for (int h = 0; h < heads; ++h) {
        double mx = -INFINITY, sum = 0;
        for (int64_t j = 0; j < N; ++j) {
          double d = 0;
          for (int c2 = 0; c2 < dh; ++c2) d += double(a[i * 3 * D + h * dh + c2]) * a[j * 3 * D + D + h * dh + c2];
          s[j] = d * scale;
          mx = std::max(mx, s[j]);
        }
        for (int64_t j = 0; j < N; ++j) sum += (s[j] = std::exp(s[j] - mx));
        for (int c2 = 0; c2 < dh; ++c2) {
          double v = 0;
          for (int64_t j = 0; j < N; ++j) v += s[j] * a[j * 3 * D + 2 * D + h * dh + c2];
          acc.add(out[i * D + h * dh + c2], v / sum);
        }
      }
    return acc.value();
  };
  cases.push_back(std::move(c));
}

// Row ops over [rows, D]: LayerNorm (weight and bias) and softmax. Memory-bound: GB/s
// counts one read and one write of the tensor.
void addRowOp(std::vector<BenchCase>& cases, Engine& engine, const std::string& op, int64_t rows, int64_t D) {
  auto x = std::make_shared<std::vector<float>>(randomValues(rows * D, 4, 3.0f));
  for (auto& v : *x) v += 2.0f;  // a mean away from 0, as activations have
  auto w = std::make_shared<std::vector<float>>(randomValues(D, 5));
  auto b = std::make_shared<std::vector<float>>(randomValues(D, 6));
  Tensor tx = engine.fromFloats({rows, D}, *x), tw = engine.fromFloats({D}, *w), tb = engine.fromFloats({D}, *b);
  Tensor ty = engine.tensor({rows, D});
  const bool ln = op == "layernorm";
  BenchCase c;
  c.name = op + "_f32";
  c.shape = std::to_string(rows) + "x" + std::to_string(D);
  c.bytes = 2.0 * rows * D * 4;
  c.record = [=](Recorder& rec) {
    if (ln) layerNorm(rec, tx, tw, tb, ty);
    else softmax(rec, tx, ty);
  };
  c.nmse = [=, &engine]() {
    auto y = engine.download(ty);
    NmseAccumulator acc;
    for (int64_t r = 0; r < rows; ++r) {
      const float* row = &(*x)[r * D];
      if (ln) {
        double mean = 0, var = 0;
        for (int64_t i = 0; i < D; ++i) mean += row[i];
        mean /= D;
        for (int64_t i = 0; i < D; ++i) var += (row[i] - mean) * (row[i] - mean);
        var /= D;
        for (int64_t i = 0; i < D; ++i)
          acc.add(y[r * D + i], (row[i] - mean) / std::sqrt(var + 1e-5) * (*w)[i] + (*b)[i]);
      } else {
        double mx = -INFINITY, sum = 0;
        for (int64_t i = 0; i < D; ++i) mx = std::max(mx, double(row[i]));
        for (int64_t i = 0; i < D; ++i) sum += std::exp(row[i] - mx);
        for (int64_t i = 0; i < D; ++i) acc.add(y[r * D + i], std::exp(row[i] - mx) / sum);
      }
    }
    return acc.value();
  };
  cases.push_back(std::move(c));
}

void addConv3x3(std::vector<BenchCase>& cases, Engine& engine, int64_t C, int64_t H, int64_t W) {
  auto x = std::make_shared<std::vector<float>>(randomValues(C * H * W, 7));
  auto w = std::make_shared<std::vector<float>>(randomValues(C * C * 9, 8, 0.1f));
  Tensor tx = engine.fromFloats({1, C, H, W}, *x), tw = engine.fromFloats({C, C, 3, 3}, *w);
  Tensor ty = engine.tensor({1, C, H, W});
  BenchCase c;
  c.name = "conv3x3_f32";
  c.shape = std::to_string(C) + "->" + std::to_string(C) + " at " + std::to_string(H) + "x" + std::to_string(W);
  c.flops = 2.0 * C * C * 9 * H * W;
  c.record = [=](Recorder& rec) { conv2d(rec, tx, tw, Tensor(), ty, {1, 1, 1}); };
  c.nmse = [=, &engine]() {
    auto y = engine.download(ty);
    NmseAccumulator acc;
    for (int64_t oy : sampleRows(H))
      for (int64_t co = 0; co < C; ++co)
        for (int64_t ox = 0; ox < W; ++ox) {
          double s = 0;
          for (int64_t ci = 0; ci < C; ++ci)
            for (int ky = 0; ky < 3; ++ky)
              for (int kx = 0; kx < 3; ++kx) {
                const int64_t iy = oy + ky - 1, ix = ox + kx - 1;
                if (iy < 0 || iy >= H || ix < 0 || ix >= W) continue;
                s += double((*x)[(ci * H + iy) * W + ix]) * (*w)[((co * C + ci) * 3 + ky) * 3 + kx];
              }
          acc.add(y[(co * H + oy) * W + ox], s);
        }
    return acc.value();
  };
  cases.push_back(std::move(c));
}

}  // namespace

std::vector<BenchCase> makeCases(Engine& engine, const std::string& only) {
  std::vector<BenchCase> cases;
  std::vector<DType> storages = {DType::F32};
  if (engine.caps().supportsFp16Storage()) storages.push_back(DType::F16);
  for (DType s : storages) {
    addGemm(cases, engine, 1024, 1024, 1024, s);
    addGemm(cases, engine, 1024, 768, 3072, s);
  }
  for (DType s : storages) {
    addAttention(cases, engine, 1280, 12, 64, s);
    addAttention(cases, engine, 2816, 12, 64, s);
  }
  for (int64_t tokens : {1280, 2816}) {
    addRowOp(cases, engine, "layernorm", tokens, 768);
    addRowOp(cases, engine, "softmax", tokens, 768);
  }
  addConv3x3(cases, engine, 64, 128, 128);
  if (!only.empty())
    std::erase_if(cases, [&](const BenchCase& c) { return c.name.find(only) == std::string::npos; });
  return cases;
}

}  // namespace spar::bench
