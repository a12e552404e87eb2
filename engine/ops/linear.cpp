#include "engine/ops/linear.h"

#include <algorithm>
#include <numeric>
#include <cstdlib>
#include <cstdio>

#include "engine/engine.h"
#include "spar/error.h"
#include "engine/kernel_plan.h"
#include "engine/ops/binding_range.h"
#include "engine/ops/cpu_tiles.h"
#include "engine/ops/op_support.h"

namespace spar {
namespace {

struct GemmPush {
  int32_t M, N, K, ldx, ldw, ldy, xBatch, wBatch, yBatch;
  int32_t yBase = 0;     // gemm_lanes.comp only: y[0][0] in y's binding
  int32_t scatterW = 0;  // gemm_lanes.comp, SCATTER_K: the input plane's width
};

// The kernel of a product and the outputs one workgroup covers (rows x columns).
struct GemmLaunch {
  const Kernel* kernel;
  int64_t rowsPerGroup, colsPerGroup;
};

// What every GEMM kernel does with a finished sum (shaders/gemm_epilogue.glsl): the activation,
// the bias, a layer scale (SCALED: the bias binding holds (bias, scale, 0, 0) texels), and the
// residual add (ACCUMULATE: y += the result).
struct Epilogue {
  Activation act = Activation::None;
  bool bias = false, accumulate = false, scaled = false;
};

// ACCUMULATE and SCALED are specialization constants 15 and 16 of every GEMM kernel: set only
// where asked, so that the kernels without them keep their constants as they were.
constexpr size_t kAccumulateId = 15, kScaledId = 16;
void withFlag(std::vector<int32_t>& constants, size_t id, bool on) {
  if (!on) return;
  if (constants.size() <= id) constants.resize(id + 1, 0);
  constants[id] = 1;
}
void withEpilogueFlags(std::vector<int32_t>& constants, const Epilogue& e) {
  withFlag(constants, kAccumulateId, e.accumulate);
  withFlag(constants, kScaledId, e.scaled);
}
// x, w and bias as texels; y written, or read and written (ACCUMULATE).
std::vector<Bind> outputBinds(bool accumulate) {
  return {Bind::Texel, Bind::Texel, Bind::Texel, accumulate ? Bind::ReadWrite : Bind::Write};
}

// gemm_lanes.comp (KernelPlan::gemmLanesSplitK): 4 rows x 8 columns a subgroup, 2 subgroups a
// workgroup: on SwiftShader (1024^3) 4.7 GFLOPS, against 3.7-3.9 for 4 x 4 and 8 x 8 and 4.1
// for 8 x 4 with 4 subgroups. biasPerRow: bias[m] (conv2d's im2col products) instead of bias[n];
// scatterK: conv_transpose2d's output blocks (gemm_lanes.comp, SCATTER_K).
GemmLaunch lanesLaunch(Engine& engine, int texelK, const Epilogue& e, bool biasPerRow, int scatterK = 0) {
  const int lanes = int(engine.caps().subgroupSize), rows = 4, cols = 8, subgroups = 2;
  std::vector<int32_t> constants = {lanes, subgroups, 1, rows, cols, texelK, static_cast<int>(e.act), e.bias, lanes,
                                    biasPerRow, scatterK};
  withEpilogueFlags(constants, e);
  const Kernel& k = engine.kernel({"gemm_lanes_f32", outputBinds(e.accumulate), sizeof(GemmPush), constants, uint32_t(lanes),
                                   engine.plan().freezeConstants});
  return {&k, rows, int64_t(cols) * subgroups};
}

// By the device's plan (engine/kernel_plan.h): gemm.comp's register blocks on CPU devices
// (gemm_lanes.comp for fp32 x and w where the plan splits k among lanes), gemm_tiled.comp's
// shared-memory tiles on GPUs (fp16 arithmetic for fp16 weights where the plan says so),
// gemm_coopmat.comp for fp16 and quantized weights where the device has cooperative matrices.
GemmLaunch gemmLaunch(Engine& engine, DType xType, DType wType, DType yType, int64_t M, int64_t N, int64_t B, int64_t K,
                      int texelK, const Epilogue& e) {
  const DeviceCaps& caps = engine.caps();
  const KernelPlan& plan = engine.plan();
  const bool f16Out = yType == DType::F16;
  // Quantized weights: gemm.comp's register blocks, gemm_tiled.comp's tiles or gemm_coopmat.comp's
  // fp16 slices dequantize them as they read them (KernelPlan::quantizedGemm).
  const KernelFamily family = isQuantized(wType)    ? plan.quantizedGemm()
                              : wType == DType::F16 ? plan.gemmF16
                                                    : plan.gemm;
  if (family == KernelFamily::CoopMat) {
    const CoopMatTiles& c = plan.coop;
    // Full subgroups of the largest size the device may use (what REQUIRE_FULL_SUBGROUPS
    // needs the workgroup's x size to be a multiple of); the shader counts them itself.
    const uint32_t subgroup = caps.maxSubgroupSize;
    const int local = int(subgroup) * c.sgM * c.sgN;
    std::vector<int32_t> constants = {local, 1, 1, c.sgM, c.sgN, c.wm, c.wn, c.kSteps, texelK, static_cast<int>(e.act),
                                      e.bias};
    if (isQuantized(wType)) constants.push_back(wType == DType::Q8 ? 8 : 4);  // W_BITS
    constants.resize(20, 0);  // ids 12-19 unused but ACCUMULATE (15), SCALED (16), PREFETCH (17); 20-22 the multiply-add shape
    withEpilogueFlags(constants, e);
    constexpr size_t kCoopPrefetchId = 17;
    constants[kCoopPrefetchId] = c.pipelined;
    constants.insert(constants.end(), {c.m, c.n, c.k});
    const std::string name = std::string(isQuantized(wType) ? "gemm_coopmat_q" : "gemm_coopmat") +
                             (f16Out ? "_f16out" : "_f32");
    const Kernel& k = engine.kernel({name, outputBinds(e.accumulate), sizeof(GemmPush), constants, subgroup});
    return {&k, c.rows(), c.cols()};
  }
  if (family == KernelFamily::Tiled) {
    const TiledGemmTiles& t = plan.tilesFor(M, N, B);
    const bool h16 = wType == DType::F16 && plan.fp16Math, quantized = isQuantized(wType);
    const std::string name = std::string(h16 ? "gemm_tiled_h16" : quantized ? "gemm_tiled_q" : "gemm_tiled") +
                             (f16Out ? "_f16out" : h16 ? "" : "_f32");
    std::vector<int32_t> constants = {t.invocations(), 1, 1, t.bm, t.bn, t.bk, t.tm, t.tn, texelK, static_cast<int>(e.act),
                                      e.bias, 1, 1, 1};
    if (quantized) constants.push_back(wType == DType::Q8 ? 8 : 4);  // W_BITS
    withEpilogueFlags(constants, e);
    t.addConstants(constants);
    const Kernel& k = engine.kernel({name, outputBinds(e.accumulate), sizeof(GemmPush), constants});
    return {&k, t.bm, t.bn};
  }
  if (family == KernelFamily::CpuBlocks && plan.gemmLanesSplitK && xType == DType::F32 && wType == DType::F32 && !f16Out)
    return lanesLaunch(engine, texelK, e, false);
  GemmTiles tiles = chooseGemmTiles(caps, engine.options().tuning, double(B) * double(M) * double(N) * double(K), N);
  // Small outputs (heads with N = 1 or 9, a handful of rows) would mostly compute clamped
  // duplicates with big blocks: on GPUs the blocks are halved down to the problem. CPU blocks
  // are small already, and every other block is one more variant to compile (0.3-0.4 s each
  // on llvmpipe) for work that takes microseconds either way.
  if (!caps.isCpu()) {
    while (tiles.colsPerInvocation > 4 && tiles.colsPerInvocation / 2 >= N) tiles.colsPerInvocation /= 2;
    while (tiles.localY > 1 && int64_t(tiles.colsPerInvocation) * tiles.localY / 2 >= N) tiles.localY /= 2;
    while (tiles.rowsPerInvocation > 4 && tiles.rowsPerInvocation / 2 >= M) tiles.rowsPerInvocation /= 2;
  }
  std::vector<int32_t> constants = {tiles.localX, tiles.localY, 1, tiles.rowsPerInvocation, tiles.colsPerInvocation,
                                    texelK, static_cast<int>(e.act), e.bias, tiles.kUnroll,
                                    isQuantized(wType) ? (wType == DType::Q8 ? 8 : 4) : 8,  // W_BITS
                                    tiles.localX,                                           // LANES
                                    engine.plan().gemmRowGroups};                           // GROUP_M
  const std::string name = std::string(tiles.sharedColumns ? "gemm_sc" : "gemm") + (isQuantized(wType) ? "_q" : "") +
                           (f16Out ? "_f16out" : "_f32");
  withEpilogueFlags(constants, e);
  // Shared columns: the workgroup must be one full subgroup (its shuffles read every lane).
  const Kernel& k = engine.kernel({name, outputBinds(e.accumulate), sizeof(GemmPush), constants,
                                   tiles.sharedColumns ? uint32_t(tiles.localX) : 0u});
  return {&k, int64_t(tiles.rowsPerInvocation) * tiles.localX, int64_t(tiles.colsPerInvocation) * tiles.localY};
}

}  // namespace

GemmTiles chooseGemmTiles(const DeviceCaps& caps, const KernelTuning& tuning, double multiplyAdds, int64_t N) {
  if (const auto& t = tuning.gemmTiles) return {(*t)[0], (*t)[1], (*t)[2], (*t)[3], (*t)[4]};
  if (caps.isCpu()) {
    const int lanes = ops::cpuLanes(caps);
    // Shared columns (gemm.comp, SHARED_COLUMNS), 1024^3 / 1024 x 768 x 3072 on one machine
    // against the register blocks below (spar-bench, GFLOPS; compile of the 4 x 32 variant):
    //   Mesa 22.3, 8 lanes:  64 / 85 against 37 / 55 (0.4 s)
    //   Mesa 22.3, 16 lanes: 79 / 95 against 65 / 69 (0.4 s)
    //   Mesa 25.0.7, 8 lanes: 68 / 90 against 16 / 25 (1.4 s)
    // 4 x 32 was the fastest of 2-4 rows x 16-64 columns everywhere. Below 2^28 multiply-adds
    // (the shipped model's GEMMs, 2^22-2^27) compile time decides: there 4 x 16, which on 22.3
    // compiles as fast as the register blocks did and runs the model 5-8 % faster (4 x 32: 7 %
    // more still, for 1.5 s more of first compiles); Mesa 25.0.7 keeps its 4 x 4 blocks there (4 x
    // 16 took the model's first compiles from 7.7 to 12.0 s). 16 columns also where N is smaller,
    // so that narrow outputs do not compute mostly clamped duplicates.
    const bool large = multiplyAdds >= double(1 << 28);
    const int columns = N >= 32 && large ? 32 : 16;
    const bool newer = ops::cpuTiles(caps) == ops::CpuTiles::Newer;
    if (ops::cpuLanesShareFetches(caps) && columns % lanes == 0 && (large || !newer))
      return {4, columns, lanes, 1, 2, true};
    switch (ops::cpuTiles(caps)) {
      // The earlier default (58-64 GFLOPS on an AVX-512 machine; 32 x 32 within noise of it at
      // ~20 s of compile per variant).
      case ops::CpuTiles::Wide: return {16, 32, lanes, 4, 2};
      // Every block from 2 x 8 to 16 x 32 ran 7-9 GFLOPS (Mesa 25.0.7): the one that compiles
      // fastest (4 x 4: 0.4 s; 16 x 32: 40 s).
      case ops::CpuTiles::Newer: return {4, 4, lanes, 8, 2};
      // By the product's multiply-adds (medians of interleaved spar-bench runs against the
      // earlier 16 x 32 everywhere):
      //   < 2^28 (the shipped model's, 2^22-2^27): 4 x 16, as fast (17-23 GFLOPS at 512 x 384 x
      //     128 .. 770 x 1536 x 512) and 0.3-0.7 s to compile instead of 4-7 s;
      //   2^28 .. 2^31 (spar-bench's 1024^3): 8 x 16, as fast there with fp32 and fp16 weights
      //     (4 x 16 lost 10-15 % with fp16 ones, whose every fetch converts), 0.6-1 s;
      //   >= 2^31 (1024 x 768 x 3072, the full-size model's MLPs): 16 x 32, which stayed 5-10 %
      //     ahead there.
      case ops::CpuTiles::Mesa22:
        if (multiplyAdds >= 2147483648.0) return {16, 32, lanes, 4, 2};
        return multiplyAdds >= double(1 << 28) ? GemmTiles{8, 16, lanes, 4, 2} : GemmTiles{4, 16, lanes, 8, 2};
    }
  }
  return {4, 4, 16, 16, 1};
}

namespace {
void linearBound(Recorder& rec, const Tensor& x, const Tensor& w, const Tensor& bias, const Tensor& y, Activation act,
                 bool accumulate);
}  // namespace

// Inputs and output that start where the device cannot bind them go through tensors of their own.
void linear(Recorder& rec, const Tensor& x, const Tensor& w, const Tensor& bias, const Tensor& y, Activation act,
            bool accumulate) {
  const uint64_t storageAlign = std::max<uint64_t>(1, rec.engine().caps().minStorageBufferOffsetAlignment);
  if (y.defined() && y.dtype() == DType::F32 && y.byteOffset() % storageAlign) {
    const Tensor out = rec.engine().tensor(y.shape(), y.dtype());
    const Tensor flatOut = out.reshape({out.numel()}), flatY = y.reshape({y.numel()});
    if (accumulate) copy2d(rec, flatY, y.numel(), 0, flatOut, out.numel(), 0, 1, y.numel());
    linearBound(rec, ops::alignedInput(rec, x, true), w, ops::alignedInput(rec, bias, true), out, act, accumulate);
    copy2d(rec, flatOut, out.numel(), 0, flatY, y.numel(), 0, 1, y.numel());
    return;
  }
  linearBound(rec, ops::alignedInput(rec, x, true), w, ops::alignedInput(rec, bias, true), y, act, accumulate);
}

namespace {
void linearBound(Recorder& rec, const Tensor& x, const Tensor& w, const Tensor& bias, const Tensor& y, Activation act,
                 bool accumulate) {
  Engine& engine = rec.engine();
  const DeviceCaps& caps = engine.caps();
  if (w.rank() != 2 && w.rank() != 3) throw Error("linear: weight must be [N, K] or [B, N, K], got " + w.describe());
  const bool batched = w.rank() == 3;
  const int64_t K = w.dim(-1), N = w.dim(-2);
  if (x.dim(-1) != K) throw Error("linear: input " + x.describe() + " does not match weight " + w.describe());
  const int64_t B = batched ? w.dim(0) : 1;
  if (batched && (x.rank() != 3 || x.dim(0) != B || y.rank() != 3 || y.dim(0) != B))
    throw Error("linear: batched weight " + w.describe() + " needs x [B, M, K] and y [B, M, N]");
  const int64_t M = batched ? x.dim(1) : x.numel() / K;
  if (y.dim(-1) != N || y.numel() != B * M * N)
    throw Error("linear: output " + y.describe() + " should hold " + std::to_string(M) + " x " + std::to_string(N));
  // a layer-scaled output: [N, 4] texels (bias, scale, 0, 0), layerScaleEpilogue()
  const bool scaled = bias.defined() && bias.rank() == 2 && bias.dim(1) == 4;
  if (bias.defined() && (scaled ? bias.dim(0) != N || bias.dtype() != DType::F32 : bias.numel() != N))
    throw Error("linear: bias " + bias.describe() + " should have " + std::to_string(N) + " values or be f32 [" +
                std::to_string(N) + ", 4] (bias, scale) texels");
  if (y.dtype() == DType::I32 || x.dtype() == DType::I32 || w.dtype() == DType::I32)
    throw Error("linear: integer tensors are not supported");
  const bool quantized = isQuantized(w.dtype());
  if (quantized && batched) throw Error("linear: a quantized weight " + w.describe() + " cannot be batched");
  if (M == 0 || N == 0) return;
  if (K == 0) throw Error("linear: K = 0");

  const int texelK = K % 4 == 0 ? 4 : 1;  // K of a quantized weight is a multiple of 32
  // w's binding: its texels (texelK values each), or a quantized row's 32-bit words
  const int wComponents = quantized ? 1 : texelK;
  const int64_t wRowTexels = quantized ? int64_t(rowBytes(w.dtype(), K) / 4) : K / texelK;
  const int64_t kTexels = K / texelK;
  const GemmLaunch launch =
      gemmLaunch(engine, x.dtype(), w.dtype(), y.dtype(), M, N, B, K, texelK, {act, bias.defined(), accumulate, scaled});
  const int biasComponents = scaled ? 4 : 1;
  const auto output = [accumulate](const Tensor& t) { return accumulate ? Arg::inout(t) : Arg::out(t); };
  const Kernel& kernel = *launch.kernel;
  const Tensor biasArg = bias.defined() ? bias : w;

  if (batched) {
    GemmPush push{int32_t(M), int32_t(N), int32_t(kTexels), int32_t(kTexels), int32_t(kTexels), int32_t(N),
                  int32_t(M * kTexels), int32_t(N * kTexels), int32_t(M * N)};
    rec.dispatch(kernel, {Arg::texel(x, texelK), Arg::texel(w, texelK), Arg::texel(biasArg, biasComponents), output(y)}, push,
                 ops::ceilDiv(M, launch.rowsPerGroup), ops::ceilDiv(N, launch.colsPerGroup), static_cast<uint32_t>(B));
    return;
  }

  // Split so that no binding exceeds the device's storage range or texel count: rows of x and
  // y (M) in chunks, and where the weight is longer than one texel binding (65536 texels on
  // the smallest devices) its rows (N) too, each chunk writing its block of y's columns.
  // Chunk starts are multiples of steps that keep every binding's offset where the device
  // can bind it (the tensors themselves start aligned).
  const uint64_t ySize = dtypeSize(y.dtype()), xSize = dtypeSize(x.dtype()), wRowBytes = rowBytes(w.dtype(), K);
  const uint64_t tAlign = ops::bindingAlignment(caps, true);
  const uint64_t sAlign = std::max<uint64_t>(1, caps.minStorageBufferOffsetAlignment);
  auto stepFor = [](uint64_t bytesPerUnit, uint64_t align) { return align / std::gcd(bytesPerUnit, align); };
  const uint64_t stepM = std::lcm(stepFor(uint64_t(K) * xSize, tAlign), stepFor(uint64_t(N) * ySize, sAlign));
  const uint64_t stepN = std::lcm(std::lcm(stepFor(ySize, sAlign), stepFor(wRowBytes, tAlign)), stepFor(4, tAlign));
  const uint64_t texelLimit = ops::texelInputLimit(engine, texelK);
  const uint64_t wTexelLimit = ops::texelInputLimit(engine, wComponents);
  int64_t chunkN = N;
  if (uint64_t(N) * uint64_t(wRowTexels) > wTexelLimit) {
    chunkN = static_cast<int64_t>(wTexelLimit / uint64_t(wRowTexels) / stepN * stepN);
    if (chunkN <= 0) throw Error("linear: one row of weight " + w.describe() + " exceeds the device's texel-buffer size");
  }
  const uint64_t rowsByY = engine.device().bindingRangeLimit() / (uint64_t(N) * ySize);
  const uint64_t rowsByX = texelLimit / uint64_t(kTexels);
  int64_t chunk = static_cast<int64_t>(std::min<uint64_t>(rowsByY, rowsByX));
  if (chunk < M) chunk = static_cast<int64_t>(uint64_t(chunk) / stepM * stepM);
  if (chunk <= 0) throw Error("linear: one row of " + y.describe() + " exceeds the device's binding limits");
  const Tensor x2 = x.reshape({M, K}), y2 = y.reshape({M, N});
  const Tensor b1 = bias.defined() ? bias.reshape({N * biasComponents}) : Tensor();
  for (int64_t m0 = 0; m0 < M; m0 += chunk) {
    const int64_t rows = std::min(chunk, M - m0);
    for (int64_t n0 = 0; n0 < N; n0 += chunkN) {
      const int64_t cols = std::min(chunkN, N - n0);
      GemmPush push{int32_t(rows), int32_t(cols), int32_t(kTexels), int32_t(kTexels), int32_t(wRowTexels), int32_t(N),
                    0, 0, 0};
      const Tensor wPart = cols == N ? w : w.reshape({N, K}).view(n0 * K, {cols, K});
      const Tensor xPart = x2.view(m0 * K, {rows, K});
      // Without a bias the binding is a placeholder never read: the weight, or one element of
      // it where the weight as R texels would be longer than a texel binding (of x for a
      // quantized weight, whose words are no float texels).
      const Tensor bPart = bias.defined() ? (cols == N ? biasArg : b1.view(n0 * biasComponents, {cols * biasComponents}))
                           : quantized ? xPart.reshape({xPart.numel()}).view(0, {1})
                           : uint64_t(wPart.numel()) <= ops::texelInputLimit(engine, 1) ? wPart
                                                                                    : wPart.reshape({wPart.numel()}).view(0, {1});
      rec.dispatch(kernel,
                   {Arg::texel(xPart, texelK), Arg::texel(wPart, wComponents), Arg::texel(bPart, bias.defined() ? biasComponents : 1),
                    output(y2.view(m0 * N + n0, {(rows - 1) * N + cols}))},
                   push, ops::ceilDiv(rows, launch.rowsPerGroup), ops::ceilDiv(cols, launch.colsPerGroup), 1);
    }
  }
}

}  // namespace

Tensor layerScaleEpilogue(Engine& engine, const Tensor& bias, const Tensor& gamma) {
  if (!gamma.defined() || gamma.rank() != 1 || (bias.defined() && bias.shape() != gamma.shape()))
    throw Error("layerScaleEpilogue: gamma " + (gamma.defined() ? gamma.describe() : std::string("(none)")) +
                " must be [N] and the bias, if any, as long");
  const int64_t N = gamma.dim(0);
  const std::vector<float> g = engine.download(gamma), b = bias.defined() ? engine.download(bias) : std::vector<float>{};
  std::vector<float> texels(size_t(4 * N), 0.0f);
  for (int64_t n = 0; n < N; ++n) {
    texels[size_t(4 * n)] = b.empty() ? 0.0f : b[size_t(n)];
    texels[size_t(4 * n + 1)] = g[size_t(n)];
  }
  return engine.fromFloats({N, 4}, texels);
}

void gemmLanesRowBias(Recorder& rec, const Tensor& a, const Tensor& b, const Tensor& bias, const Tensor& y, int64_t ldy,
                      Activation act, int scatterK, int64_t scatterW) {
  Engine& engine = rec.engine();
  if (!engine.plan().gemmLanesSplitK) throw Error("gemmLanesRowBias: the device's plan has no lanes GEMM");
  if (a.rank() != 2 || b.rank() != 2 || a.dim(1) != b.dim(1) || a.dtype() != DType::F32 || b.dtype() != DType::F32 ||
      y.dtype() != DType::F32)
    throw Error("gemmLanesRowBias: a " + a.describe() + " and b " + b.describe() + " must be fp32 [M, K] and [N, K]");
  const int64_t M = a.dim(0), N = b.dim(0), K = a.dim(1);
  if (M == 0 || N == 0) return;
  if (K == 0) throw Error("gemmLanesRowBias: K = 0");
  const int64_t kk = int64_t(scatterK) * scatterK;
  if (scatterK > 0 && (M % kk || scatterW < 1 || N % scatterW))
    throw Error("gemmLanesRowBias: " + std::to_string(M) + " x " + std::to_string(N) + " is no set of " +
                std::to_string(scatterK) + "x" + std::to_string(scatterK) + " blocks of rows " + std::to_string(scatterW) +
                " wide");
  // the elements from y[0][0] to the last one written
  const int64_t span = scatterK > 0 ? (M / kk - 1) * ldy + N * kk : (M - 1) * ldy + N;
  if (ldy < (scatterK > 0 ? N * kk : N) || y.numel() != span)
    throw Error("gemmLanesRowBias: y " + y.describe() + " does not hold " + std::to_string(M) + " rows of " +
                std::to_string(N) + " a stride " + std::to_string(ldy) + " apart");
  if (bias.defined() && bias.numel() != (scatterK > 0 ? M / kk : M))
    throw Error("gemmLanesRowBias: bias " + bias.describe() + " does not match " + std::to_string(M) + " rows");
  const int texelK = K % 4 == 0 ? 4 : 1;
  const GemmLaunch launch = lanesLaunch(engine, texelK, {act, bias.defined()}, true, scatterK);
  const Tensor ax = ops::alignedInput(rec, a, true), bx = ops::alignedInput(rec, b, true);
  const Tensor biasArg = bias.defined() ? ops::alignedInput(rec, bias, true) : ax;
  const ops::BoundRange yr = ops::bindRange(engine.caps(), y, 0, y.numel(), false);
  const int32_t kTexels = int32_t(K / texelK);
  GemmPush push{int32_t(M), int32_t(N), kTexels, kTexels, kTexels, int32_t(ldy), 0, 0, 0, -yr.base, int32_t(scatterW)};
  rec.dispatch(*launch.kernel, {Arg::texel(ax, texelK), Arg::texel(bx, texelK), Arg::texel(biasArg, 1), Arg::out(yr.view)},
               push, ops::ceilDiv(M, launch.rowsPerGroup), ops::ceilDiv(N, launch.colsPerGroup), 1);
}

}  // namespace spar
