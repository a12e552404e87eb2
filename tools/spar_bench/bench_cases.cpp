#include "tools/spar_bench/bench_cases.h"

#include <cmath>
#include <random>


namespace spar::bench {
namespace {

std::vector<float> randomValues(size_t n, uint32_t seed, float scale = 1.0f) {
  std::mt19937 rng(seed);
  std::vector<float> v(n);
  for (auto& x : v) x = uniformFloat(rng, -scale, scale);
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

// The cases being made and the filter they are made for: a case whose name the filter rules
// out is never made, so `--only` uploads no other case's inputs (SAM2's alone are ~200 MB).
struct CaseList {
  std::vector<BenchCase> cases;
  std::string only;
  bool wants(const std::string& name) const { return only.empty() || name.find(only) != std::string::npos; }
  void push_back(BenchCase c) { cases.push_back(std::move(c)); }
};

void addGemm(CaseList& cases, Engine& engine, int64_t M, int64_t K, int64_t N, DType storage,
             const std::string& prefix = "") {
  const std::string name = prefix + (storage == DType::F16 ? "gemm_f16" : "gemm_f32");
  if (!cases.wants(name)) return;
  auto x = std::make_shared<std::vector<float>>(randomValues(M * K, 1));
  auto w = std::make_shared<std::vector<float>>(randomValues(N * K, 2, 0.05f));
  Tensor tx = engine.fromFloats({M, K}, *x, storage), tw = engine.fromFloats({N, K}, *w, storage);
  Tensor ty = engine.tensor({M, N}, storage);
  BenchCase c;
  c.name = name;
  c.shape = std::to_string(M) + "x" + std::to_string(K) + "x" + std::to_string(N);
  c.flops = 2.0 * M * N * K;
  c.peer = {{"op", "gemm"}, {"m", M}, {"k", K}, {"n", N}};
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

// Self-attention of B independent sequences of N tokens (B > 1: windows, as SAM2's Hiera has).
void addAttention(CaseList& cases, Engine& engine, int64_t N, int heads, int dh, DType storage,
                  int64_t B = 1, const std::string& prefix = "") {
  const std::string name = prefix + (storage == DType::F16 ? "attention_f16" : "attention_f32");
  if (!cases.wants(name)) return;
  const int64_t D = int64_t(heads) * dh;
  auto qkv = std::make_shared<std::vector<float>>(randomValues(B * N * 3 * D, 3, 1.5f));
  Tensor t = engine.fromFloats({B, N, 3 * D}, *qkv, storage);
  Tensor o = engine.tensor({B, N, D}, storage);
  BenchCase c;
  c.name = name;
  c.shape = std::to_string(heads) + "x" + std::to_string(dh) + " heads, " +
            (B > 1 ? std::to_string(B) + " windows of " : std::string()) + std::to_string(N) + " tokens";
  c.flops = 4.0 * double(B) * N * N * dh * heads;
  c.peer = {{"op", "attention"}, {"batch", B}, {"tokens", N}, {"heads", heads}, {"dim", dh}};
  c.record = [=](Recorder& rec) { attention(rec, {t, 0}, {t, D}, {t, 2 * D}, {o, 0}, heads, dh); };
  c.nmse = [=, &engine]() {
    auto out = engine.download(o);
    const auto& a = *qkv;
    NmseAccumulator acc;
    std::vector<double> s(N);
    const double scale = 1.0 / std::sqrt(double(dh));
    for (int64_t i : sampleRows(B * N))
      for (int h = 0; h < heads; ++h) {
        const int64_t first = (i / N) * N;  // the keys of row i's own sequence
        double mx = -INFINITY, sum = 0;
        for (int64_t j = 0; j < N; ++j) {
          double d = 0;
          for (int c2 = 0; c2 < dh; ++c2)
            d += double(a[i * 3 * D + h * dh + c2]) * a[(first + j) * 3 * D + D + h * dh + c2];
          s[j] = d * scale;
          mx = std::max(mx, s[j]);
        }
        for (int64_t j = 0; j < N; ++j) sum += (s[j] = std::exp(s[j] - mx));
        for (int c2 = 0; c2 < dh; ++c2) {
          double v = 0;
          for (int64_t j = 0; j < N; ++j) v += s[j] * a[(first + j) * 3 * D + 2 * D + h * dh + c2];
          acc.add(out[i * D + h * dh + c2], v / sum);
        }
      }
    return acc.value();
  };
  cases.push_back(std::move(c));
}

// Row ops over [rows, D]: LayerNorm (weight and bias) and softmax. Memory-bound: GB/s
// counts one read and one write of the tensor.
void addRowOp(CaseList& cases, Engine& engine, const std::string& op, int64_t rows, int64_t D) {
  if (!cases.wants(op + "_f32")) return;
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
  c.peer = {{"op", op}, {"rows", rows}, {"cols", D}};
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

void addConv3x3(CaseList& cases, Engine& engine, int64_t C, int64_t H, int64_t W) {
  if (!cases.wants("conv3x3_f32")) return;
  auto x = std::make_shared<std::vector<float>>(randomValues(C * H * W, 7));
  auto w = std::make_shared<std::vector<float>>(randomValues(C * C * 9, 8, 0.1f));
  Tensor tx = engine.fromFloats({1, C, H, W}, *x), tw = engine.fromFloats({C, C, 3, 3}, *w);
  Tensor ty = engine.tensor({1, C, H, W});
  BenchCase c;
  c.name = "conv3x3_f32";
  c.shape = std::to_string(C) + "->" + std::to_string(C) + " at " + std::to_string(H) + "x" + std::to_string(W);
  c.flops = 2.0 * C * C * 9 * H * W;
  c.peer = {{"op", "conv2d"}, {"n", 1}, {"cin", C}, {"cout", C}, {"h", H}, {"w", W}, {"k", 3}, {"pad", 1}};
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

// GELU in float64 (the decoder fuses it into every conv).
double geluRef(double v) { return 0.5 * v * std::erfc(-v / std::sqrt(2.0)); }

// One conv of the CV-DRP decoder (model/cv_drp.cpp) at its full-size shape: N images,
// k x k kernel, padding (k - 1) / 2, bias and GELU fused as the decoder runs it.
void addDecoderConv(CaseList& cases, Engine& engine, const std::string& name, int64_t N, int64_t Cin,
                    int64_t Cout, int64_t H, int64_t W, int64_t k) {
  if (!cases.wants(name)) return;
  auto x = std::make_shared<std::vector<float>>(randomValues(N * Cin * H * W, 11));
  auto w = std::make_shared<std::vector<float>>(randomValues(Cout * Cin * k * k, 12, 1.0f / std::sqrt(float(Cin * k * k))));
  auto b = std::make_shared<std::vector<float>>(randomValues(Cout, 13, 0.1f));
  Tensor tx = engine.fromFloats({N, Cin, H, W}, *x), tw = engine.fromFloats({Cout, Cin, k, k}, *w);
  Tensor tb = engine.fromFloats({Cout}, *b), ty = engine.tensor({N, Cout, H, W});
  const int pad = int(k - 1) / 2;
  BenchCase c;
  c.name = name;
  c.shape = std::to_string(N) + "x" + std::to_string(Cin) + "->" + std::to_string(Cout) + " k" + std::to_string(k) +
            " at " + std::to_string(H) + "x" + std::to_string(W);
  c.flops = 2.0 * N * Cout * Cin * k * k * H * W;
  c.peer = {{"op", "conv2d"}, {"n", N},   {"cin", Cin}, {"cout", Cout}, {"h", H},
            {"w", W},         {"k", k},   {"pad", pad}, {"bias", true}, {"gelu", true}};
  c.record = [=](Recorder& rec) {
    conv2d(rec, tx, tw, tb, ty, {.stride = 1, .padY = pad, .padX = pad, .act = Activation::Gelu});
  };
  c.nmse = [=, &engine]() {
    auto y = engine.download(ty);
    NmseAccumulator acc;
    for (int64_t r : sampleRows(N * H)) {
      const int64_t n = r / H, oy = r % H;
      for (int64_t co = 0; co < Cout; ++co)
        for (int64_t ox = 0; ox < W; ++ox) {
          double s = (*b)[co];
          for (int64_t ci = 0; ci < Cin; ++ci)
            for (int64_t ky = 0; ky < k; ++ky)
              for (int64_t kx = 0; kx < k; ++kx) {
                const int64_t iy = oy + ky - pad, ix = ox + kx - pad;
                if (iy < 0 || iy >= H || ix < 0 || ix >= W) continue;
                s += double((*x)[((n * Cin + ci) * H + iy) * W + ix]) * (*w)[((co * Cin + ci) * k + ky) * k + kx];
              }
          acc.add(y[((n * Cout + co) * H + oy) * W + ox], geluRef(s));
        }
    }
    return acc.value();
  };
  cases.push_back(std::move(c));
}

// One transposed conv (kernel = stride = 2) of the CV-DRP decoder at its full-size shape:
// N images of H x W in, bias and GELU fused.
void addDecoderConvT(CaseList& cases, Engine& engine, const std::string& name, int64_t N, int64_t Cin,
                     int64_t Cout, int64_t H, int64_t W) {
  if (!cases.wants(name)) return;
  constexpr int64_t k = 2;
  auto x = std::make_shared<std::vector<float>>(randomValues(N * Cin * H * W, 14));
  auto w = std::make_shared<std::vector<float>>(randomValues(Cin * Cout * k * k, 15, 1.0f / std::sqrt(float(Cin))));
  auto b = std::make_shared<std::vector<float>>(randomValues(Cout, 16, 0.1f));
  Tensor tx = engine.fromFloats({N, Cin, H, W}, *x), tw = engine.fromFloats({Cin, Cout, k, k}, *w);
  Tensor tb = engine.fromFloats({Cout}, *b), ty = engine.tensor({N, Cout, H * k, W * k});
  BenchCase c;
  c.name = name;
  c.shape = std::to_string(N) + "x" + std::to_string(Cin) + "->" + std::to_string(Cout) + " k2s2 from " +
            std::to_string(H) + "x" + std::to_string(W);
  c.flops = 2.0 * N * Cout * Cin * k * k * H * W;
  c.peer = {{"op", "conv_transpose2d"}, {"n", N}, {"cin", Cin}, {"cout", Cout}, {"h", H},
            {"w", W},                   {"k", k}, {"bias", true}, {"gelu", true}};
  c.record = [=](Recorder& rec) { convTranspose2d(rec, tx, tw, tb, ty, Activation::Gelu); };
  c.nmse = [=, &engine]() {
    auto y = engine.download(ty);
    const int64_t Ho = H * k, Wo = W * k;
    NmseAccumulator acc;
    for (int64_t r : sampleRows(N * Ho)) {
      const int64_t n = r / Ho, oy = r % Ho;
      for (int64_t co = 0; co < Cout; ++co)
        for (int64_t ox = 0; ox < Wo; ++ox) {
          double s = (*b)[co];
          for (int64_t ci = 0; ci < Cin; ++ci)
            s += double((*x)[((n * Cin + ci) * H + oy / k) * W + ox / k]) *
                 (*w)[((ci * Cout + co) * k + oy % k) * k + ox % k];
          acc.add(y[((n * Cout + co) * Ho + oy) * Wo + ox], geluRef(s));
        }
    }
    return acc.value();
  };
  cases.push_back(std::move(c));
}

// The CV-DRP decoder's convolutions at the official size (16x16 tokens -> 256x256), for the
// 4 images of 2 view pairs, in decoder order (`--only drp_` runs them all).
void addDecoderCases(CaseList& cases, Engine& engine) {
  constexpr int64_t N = 4;
  const int64_t chans[] = {256, 128, 64, 32};
  int64_t s = 16;
  for (int i = 0; i < 3; ++i) {
    const std::string up = "drp_up" + std::to_string(i);
    addDecoderConvT(cases, engine, up + "_convt", N, chans[i], chans[i + 1], s, s);
    s *= 2;
    addDecoderConv(cases, engine, up + "_conv3x3", N, chans[i + 1], chans[i + 1], s, s, 3);
  }
  addDecoderConvT(cases, engine, "drp_final_convt", N, 32, 16, s, s);
  addDecoderConv(cases, engine, "drp_head_conv1x1", N, 16, 1, 2 * s, 2 * s, 1);
}

// SAM2.1 hiera_l's largest shapes per view (docs/sam2.md: 1.83 TFLOP, the image encoder 99.8 %
// of it; `--only sam2_` runs them): stage 1's qkv GEMM (65536 tokens of 144) and its attention
// in 1024 windows of 8x8, stage 3's MLP GEMM (4096 tokens of 576 -> 2304), its attention in 16
// windows of 16x16, and its global blocks over all 4096 tokens (8 heads of 72).
void addSam2Cases(CaseList& cases, Engine& engine, DType s) {
  addGemm(cases, engine, 65536, 144, 432, s, "sam2_l_s1_qkv_");
  addGemm(cases, engine, 4096, 576, 2304, s, "sam2_l_s3_mlp_");
  addAttention(cases, engine, 64, 2, 72, s, 1024, "sam2_l_s1_window_");
  addAttention(cases, engine, 256, 8, 72, s, 16, "sam2_l_s3_window_");
  addAttention(cases, engine, 4096, 8, 72, s, 1, "sam2_l_global_");
}

// The device's arithmetic ceiling (shaders/peak_flops.comp): multiply-add chains on registers,
// no memory traffic, so the GEMMs' GFLOPS can be read against what the device can do at all.
// Its "NMSE" is the relative error of one invocation's result against float64 (a check that
// the work was done, not a precision claim).
void addPeak(CaseList& cases, Engine& engine, int chains, bool useFma, int unroll) {
  if (!cases.wants(std::string("peak_") + (useFma ? "fma" : "mul_add") + "_f32")) return;
  const int64_t invocations = 1 << 18;
  const int iterations = 1024;
  Tensor ty = engine.tensor({invocations});
  const int32_t local = 64;
  const Kernel& k = engine.kernel({"peak_flops", {Bind::Write}, 12, {local, 1, 1, chains, useFma, unroll}});
  struct Push { int32_t iterations; float a, b; } push{iterations, 0.999f, 0.001f};
  BenchCase c;
  c.name = std::string("peak_") + (useFma ? "fma" : "mul_add") + "_f32";
  c.shape = std::to_string(chains) + " chains x " + std::to_string(iterations) + ", unrolled " + std::to_string(unroll);
  c.flops = 2.0 * double(invocations) * iterations * chains;
  c.record = [=, &k](Recorder& rec) { rec.dispatch(k, {Arg::out(ty)}, push, uint32_t(invocations / local)); };
  c.nmse = [=, &engine]() {
    auto y = engine.download(ty);
    const int64_t i = invocations / 3;
    double ref = 0;
    for (int j = 0; j < chains; ++j) {
      double v = double(i + j);
      for (int it = 0; it < iterations; ++it) v = v * double(push.a) + double(push.b);
      ref += v;
    }
    return (y[i] - ref) * (y[i] - ref) / (ref * ref);
  };
  cases.push_back(std::move(c));
}

}  // namespace

std::vector<BenchCase> makeCases(Engine& engine, const std::string& only, bool large) {
  CaseList cases{{}, only};
  for (int chains : {8, 16, 32})
    for (int unroll : {1, 8}) addPeak(cases, engine, chains, true, unroll);
  addPeak(cases, engine, 16, false, 8);
  std::vector<DType> storages = {DType::F32};
  if (engine.caps().supportsFp16Storage()) storages.push_back(DType::F16);
  for (DType s : storages) {
    addGemm(cases, engine, 1024, 1024, 1024, s);
    addGemm(cases, engine, 1024, 768, 3072, s);
    // The size GPU libraries are compared at (issue 15's bar: cuBLAS on the same GPU).
    if (large) addGemm(cases, engine, 4096, 4096, 4096, s);
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
  addDecoderCases(cases, engine);
  for (DType s : storages) addSam2Cases(cases, engine, s);
  return std::move(cases.cases);
}

}  // namespace spar::bench
