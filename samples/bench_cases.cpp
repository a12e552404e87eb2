#include "samples/bench_cases.h"

#include <cmath>
#include <random>

#include "engine/ops/attention.h"
#include "engine/ops/linear.h"

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
  if (!only.empty())
    std::erase_if(cases, [&](const BenchCase& c) { return c.name.find(only) == std::string::npos; });
  return cases;
}

}  // namespace spar::bench
