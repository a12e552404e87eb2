// Host side of shaders/conv2d.comp.
#include "engine/ops/conv2d.h"

#include <cstdio>
#include <cstdlib>
#include <numeric>

#include "engine/ops/binding_range.h"
#include "engine/ops/cpu_tiles.h"
#include "engine/ops/im2col.h"
#include "engine/ops/linear.h"

namespace spar {
namespace {

struct ConvPush {
  int32_t Cin, H, W, Cout, Ho, Wo, padY, padX, coBlocks, zBase, inBase, wBase, biasBase, outBase;
};

// shaders/gemm_tiled.comp, CONV: the push block of its convolution.
struct ConvGemmPush {
  int32_t Cin, H, W, Cout, Ho, Wo, padY, padX, wRow, inBase, wBase, biasBase, outBase, blocks, blockChannels, zBase;
};

// The GPU family: convolution as an implicit GEMM (M = output pixels of an image, N = Cout,
// K = Cin*kh*kw, the weight as PyTorch stores it is the [N, K] matrix), one workgroup layer
// per work unit (an image, or a block of its output channels when one image's output is
// larger than a binding).
// A quantized w (the [Cout, Cin*KH*KW] matrix) is bound whole as its words and dequantized
// while its tiles are copied (conv2d_tiled_q_f32).
void conv2dAsGemm(Recorder& rec, const Tensor& x, const Tensor& w, const Tensor& bias, const Tensor& y,
                  const Conv2dParams& params, int64_t KH, int64_t KW) {
  using namespace ops;
  Engine& engine = rec.engine();
  const DeviceCaps& caps = engine.caps();
  const bool quantized = isQuantized(w.dtype());
  const int64_t N = x.dim(0), Cin = x.dim(1), H = x.dim(2), W = x.dim(3);
  const int64_t Cout = w.dim(0), Ho = y.dim(2), Wo = y.dim(3);
  const int64_t depth = Cin * KH * KW;
  const TiledGemmTiles& t = engine.plan().tilesFor(Ho * Wo, Cout, N);
  const BoundRange wr = quantized ? BoundRange{w, 0} : bindRange(caps, w, 0, w.numel(), true);
  const BoundRange br = bias.defined() ? bindRange(caps, bias, 0, Cout, true) : wr;
  // Weight rows as RGBA texels when they are whole texels from a texel-aligned start.
  const int texelK = depth % 4 == 0 && wr.base % 4 == 0 ? 4 : 1;
  const int wComponents = quantized ? 1 : texelK;
  if (uint64_t(quantized ? w.bytes() / 4 : wr.view.numel() / texelK) > ops::texelInputLimit(engine, wComponents))
    throw Error("conv2d: weight " + w.describe() + " exceeds the device's texel-buffer size");
  std::vector<int32_t> constants = {t.invocations(), 1, 1, t.bm, t.bn, t.bk, t.tm, t.tn, texelK,
                                    static_cast<int>(params.act), bias.defined(), int(KH), int(KW), params.stride};
  if (quantized) constants.push_back(w.dtype() == DType::Q8 ? 8 : 4);  // W_BITS
  auto tiledKernel = [&](bool pointwise) {
    std::vector<int32_t> c = constants;
    t.addConstants(c, pointwise);
    return &engine.kernel({quantized ? "conv2d_tiled_q_f32" : "conv2d_tiled_f32",
                           {Bind::Texel, Bind::Texel, Bind::Texel, Bind::Write}, sizeof(ConvGemmPush), c});
  };
  const Kernel& kernel = *tiledKernel(false);
  // A 1x1 convolution, stride 1, no padding, over whole texels of pixels: a plain GEMM reading
  // the image as RGBA texels (gemm_tiled.comp's POINTWISE), in every chunk whose binding starts
  // on a texel of the image (the views below start 16-byte aligned, so all do).
  const bool pointwise = KH == 1 && KW == 1 && params.stride == 1 && params.padY == 0 && params.padX == 0 &&
                         (H * W) % 4 == 0 && t.bm % 4 == 0 && x.byteOffset() % 16 == 0;
  const Kernel* pointwiseKernel = pointwise ? tiledKernel(true) : nullptr;
  // Output channels per unit: all of them, unless an image's output is over a binding.
  const int64_t plane = Ho * Wo;
  const int64_t room = bindingElements(engine, false) - alignmentSlack(caps, false);
  int64_t blockChannels = Cout;
  if (blockChannels * plane > room) {
    blockChannels = room / plane / t.bn * t.bn;
    if (blockChannels == 0) blockChannels = std::max<int64_t>(1, room / plane);
  }
  const int64_t blocks = ceilDiv(Cout, blockChannels);
  const uint32_t gx = ceilDiv(plane, t.bm), gy = ceilDiv(blockChannels, t.bn);
  if (gx > caps.maxWorkGroupCount[0] || gy > caps.maxWorkGroupCount[1])
    throw Error("conv2d: output " + y.describe() + " needs more workgroups than the device allows");
  forEachUnitChunk(engine, x, y, N, Cout, blockChannels, plane, 1, "conv2d", [&](const UnitChunk& c) {
    const ConvGemmPush push{int32_t(Cin), int32_t(H), int32_t(W), int32_t(Cout), int32_t(Ho), int32_t(Wo),
                            params.padY, params.padX, int32_t(depth / texelK), int32_t(-c.in.base),
                            int32_t(-wr.base / texelK), int32_t(-br.base), int32_t(-c.out.base), int32_t(blocks),
                            int32_t(blockChannels), int32_t(c.u0)};
    // without a bias a placeholder never read: the weight, or for a quantized one one element of x
    const bool texels = pointwiseKernel && c.in.base % 4 == 0 && c.in.view.numel() % 4 == 0;
    rec.dispatch(texels ? *pointwiseKernel : kernel,
                 {Arg::texel(c.in.view, texels ? 4 : 1), Arg::texel(wr.view, wComponents),
                  Arg::texel(bias.defined() || !quantized ? br.view : c.in.view.view(0, {1}), 1), Arg::out(c.out.view)},
                 push, gx, gy, static_cast<uint32_t>(c.u1 - c.u0));
  });
}

// Where the plan splits a GEMM's k among a subgroup's lanes (KernelPlan::gemmLanesSplitK,
// SwiftShader): fp32 convolutions as im2col (engine/ops/im2col.h) and that GEMM
// (gemmLanesRowBias, bias and activation in its epilogue). conv2d.comp's per-lane register
// blocks load lane by lane there (its lanes' addresses are neither equal nor consecutive):
// conv3x3 64 -> 64 at 128x128 ran at 0.3-0.5 GFLOPS at every block shape tried, 2.4 so. The
// patches of a band of output rows at a time, in the recorder's scratch; the band's products
// go straight into y's rows (a column block of y[n] as [Cout, Ho * Wo]).
// False (and nothing recorded) where a binding would not fit: conv2d.comp then runs it.
bool conv2dAsIm2colGemm(Recorder& rec, const Tensor& x, const Tensor& w, const Tensor& bias, const Tensor& y,
                        const Conv2dParams& params, int64_t KH, int64_t KW) {
  using namespace ops;
  Engine& engine = rec.engine();
  const DeviceCaps& caps = engine.caps();
  const int64_t N = x.dim(0), Cin = x.dim(1), H = x.dim(2), W = x.dim(3);
  const int64_t Cout = w.dim(0), Ho = y.dim(2), Wo = y.dim(3), K = Cin * KH * KW;
  const int64_t image = Cin * H * W, plane = Ho * Wo;
  const int64_t room = std::min(bindingElements(engine, true), bindingElements(engine, false)) - alignmentSlack(caps, true);
  const int64_t bandRows = std::min<int64_t>(Ho, kIm2colScratchBytes / 4 / std::max<int64_t>(1, K * Wo));
  if (bandRows < 1 || image > room || Cout * K > room || Cout * plane > room || bandRows * Wo * K > room) return false;
  const Tensor wm = w.reshape({Cout, K});
  // The recorder's scratch, of the cap's size whatever this call needs: one buffer serves every
  // convolution it records (the memory estimate counts one per recorder alive at once).
  const Tensor scratch = rec.scratch(kIm2colScratchBytes / 4);
  for (int64_t n = 0; n < N; ++n)
    for (int64_t oy0 = 0; oy0 < Ho; oy0 += bandRows) {
      const int64_t rows = std::min(bandRows, Ho - oy0), pixels = rows * Wo;
      const Tensor p = scratch.view(0, {pixels, K});
      im2col(rec, x, n * image, {Cin, H, W, Wo, KH, KW, params.stride, params.padY, params.padX, oy0, rows}, p);
      gemmLanesRowBias(rec, wm, p, bias, y.view(n * Cout * plane + oy0 * Wo, {(Cout - 1) * plane + pixels}), plane,
                       params.act);
    }
  return true;
}

}  // namespace

ConvTiles chooseConvTiles(const DeviceCaps& caps, const KernelTuning& tuning, int64_t kh, int64_t kw, int64_t cout) {
  if (const auto& t = tuning.convTiles) return {(*t)[0], (*t)[1], (*t)[2], (*t)[3], (*t)[4]};
  // The unrolled loop body holds channels x 4 input channels x kh x kw x rows x cols
  // multiply-adds, and its compile time grows with it: on llvmpipe (Mesa 22.3, 8 lanes)
  // 16 x 2 x 8 outputs of 3x3 (9k multiply-adds) took 3-5 s per variant, 8 x 1 x 8 (2.3k)
  // 0.8-1.0 s and ran faster (spar-bench conv3x3 and drp_*_conv3x3, medians of 3 interleaved
  // runs: 16-23 GFLOPS against 16-19; 16 x 1 x 8 another 10 % at 1.0-1.3 s), so that is the
  // CPU block and bigger kernels get fewer channels.
  // Mesa 25.0.7: 4 x 1 x 8 ran 13-14 GFLOPS against 11-12 for 8 x 1 x 8 and compiled in 0.7 s
  // instead of 2.3 s. With 16 lanes: the earlier default, 16 x 2 x 8.
  const int lanes = ops::cpuLanes(caps);
  const ops::CpuTiles family = ops::cpuTiles(caps);
  const int64_t budget = family == ops::CpuTiles::Wide ? 9216 : family == ops::CpuTiles::Newer ? 1152 : 2304;
  ConvTiles t = !caps.isCpu()                     ? ConvTiles{4, 1, 4, 16, 8}
                : family == ops::CpuTiles::Wide  ? ConvTiles{16, 2, 8, lanes, 1}
                : family == ops::CpuTiles::Newer ? ConvTiles{4, 1, 8, lanes, 1}
                                                 : ConvTiles{8, 1, 8, lanes, 1};
  // Fewer output channels than the block (CV-DRP's 16 -> 1 head): channels past Cout would be
  // computed and dropped, so the block trades them for rows (up to 8, bounding the tile, and
  // within the unrolled-body budget below).
  if (caps.isCpu() && cout < t.channels) {
    const int64_t c = std::max<int64_t>(cout, 1);
    const int64_t budgetRows = budget / (4 * std::max<int64_t>(1, kh * kw) * t.cols * c);
    t.rows = static_cast<int>(std::max<int64_t>(t.rows, std::min<int64_t>({8, t.rows * t.channels / c, budgetRows})));
    t.channels = static_cast<int>(c);
  }
  const int64_t perChannel = 4 * std::max<int64_t>(1, kh * kw) * t.rows * t.cols;
  t.channels = static_cast<int>(std::clamp<int64_t>(budget / perChannel, 1, t.channels));
  return t;
}

int64_t conv2dOutputSize(int64_t in, int64_t kernel, int stride, int pad) {
  const int64_t span = in + 2 * int64_t(pad) - kernel;
  if (stride < 1 || pad < 0 || span < 0)
    throw Error("conv2d: kernel " + std::to_string(kernel) + " with padding " + std::to_string(pad) +
                " does not fit input size " + std::to_string(in));
  return span / stride + 1;
}

void conv2d(Recorder& rec, const Tensor& x, const Tensor& w, const Tensor& bias, const Tensor& y,
            const Conv2dParams& params) {
  using namespace ops;
  Engine& engine = rec.engine();
  const DeviceCaps& caps = engine.caps();
  const bool quantized = isQuantized(w.dtype());
  requireF32(x, "conv2d", "input");
  if (!quantized) requireF32(w, "conv2d", "weight");
  requireF32(y, "conv2d", "output");
  if (bias.defined()) requireF32(bias, "conv2d", "bias");
  if (x.rank() != 4) throw Error("conv2d: input must be [N, Cin, H, W], got " + x.describe());
  if (quantized ? w.rank() != 2 || params.kernelH < 1 || params.kernelW < 1 : w.rank() != 4)
    throw Error("conv2d: weight must be [Cout, Cin, kh, kw], or a quantized [Cout, Cin*kh*kw] with the kernel size "
                "in the parameters; got " + w.describe());
  const int64_t N = x.dim(0), Cin = x.dim(1), H = x.dim(2), W = x.dim(3);
  const int64_t Cout = w.dim(0), KH = quantized ? params.kernelH : w.dim(2), KW = quantized ? params.kernelW : w.dim(3);
  if (quantized ? w.dim(1) != Cin * KH * KW : w.dim(1) != Cin)
    throw Error("conv2d: weight " + w.describe() + " does not match input " + x.describe());
  if (!quantized && ((params.kernelH && params.kernelH != KH) || (params.kernelW && params.kernelW != KW)))
    throw Error("conv2d: weight " + w.describe() + " is no " + std::to_string(params.kernelH) + "x" +
                std::to_string(params.kernelW) + " kernel");
  if (params.stride < 1 || params.padY < 0 || params.padX < 0) throw Error("conv2d: stride must be >= 1, padding >= 0");
  if (KH < 1 || KW < 1 || KH > 32 || KW > 32) throw Error("conv2d: kernel size must be 1..32, got " + w.describe());
  const int64_t Ho = conv2dOutputSize(H, KH, params.stride, params.padY);
  const int64_t Wo = conv2dOutputSize(W, KW, params.stride, params.padX);
  if (y.shape() != Shape{N, Cout, Ho, Wo})
    throw Error("conv2d: output " + y.describe() + " should be " + shapeString({N, Cout, Ho, Wo}));
  if (bias.defined() && bias.shape() != Shape{Cout})
    throw Error("conv2d: bias " + bias.describe() + " should be [" + std::to_string(Cout) + "]");
  for (const Tensor* t : {&x, &w, &y}) checkElementCount(*t, "conv2d");
  if (y.numel() == 0) return;
  if (Cin == 0) throw Error("conv2d: input has no channels");
  if ((quantized ? engine.plan().quantizedConv() : engine.plan().conv) == KernelFamily::Tiled)
    return conv2dAsGemm(rec, x, w, bias, y, params, KH, KW);
  if (!quantized && engine.plan().gemmLanesSplitK && conv2dAsIm2colGemm(rec, x, w, bias, y, params, KH, KW)) return;

  const ConvTiles tiles = chooseConvTiles(caps, engine.options().tuning, KH, KW, Cout);
  // Weights and bias may sit at any offset: they are bound from an aligned start. A quantized
  // kernel is bound whole, as its 32-bit words (a tensor of its own starts aligned).
  const BoundRange wr = quantized ? BoundRange{w, 0} : bindRange(caps, w, 0, w.numel(), true);
  const BoundRange br = bias.defined() ? bindRange(caps, bias, 0, Cout, true) : wr;
  // Input channels per step: a step's weights are whole RGBA texels when Cin*kh*kw is a
  // multiple of 4 (and the binding starts on a texel); otherwise one channel with R texels.
  // (A quantized row is whole blocks of 32: always RGBA, dequantized a texel at a time.)
  const int64_t kk = KH * KW;
  const bool rgba = (Cin * kk) % 4 == 0 && wr.base % 4 == 0;
  const int G = rgba ? int(4 / std::gcd<int64_t>(kk, 4)) : 1;
  const int wComponents = quantized ? 1 : rgba ? 4 : 1;
  if (uint64_t(quantized ? w.bytes() / 4 : wr.view.numel() / wComponents) > ops::texelInputLimit(engine, wComponents))
    throw Error("conv2d: weight " + w.describe() + " exceeds the device's texel-buffer size");
  // Input rows as RGBA texels (4 columns each) when rows and every tile start stay on texel
  // boundaries: W and cols*stride multiples of 4 and x starting on a texel.
  const bool rgbaX = W % 4 == 0 && (tiles.cols * params.stride) % 4 == 0 && x.byteOffset() % 16 == 0;
  // Workgroups of one row of invocations walk the blocks of a plane in one flat order (unless
  // a huge plane would need more workgroups along x than the device allows: then 2-D).
  const int64_t colBlocks = ceilDiv(Wo, tiles.cols), rowBlocks = ceilDiv(Ho, tiles.rows);
  const bool flat = tiles.localY == 1 && ceilDiv(colBlocks * rowBlocks, tiles.localX) <= caps.maxWorkGroupCount[0];
  // Outputs as whole vec4s (the _out4 variant) when every block row segment is: its start
  // (a multiple of cols in a row of Wo) and the binding's base on a 4-element boundary.
  const bool rowsOf4 = tiles.cols % 4 == 0 && Wo % 4 == 0;
  // The lanes of a workgroup (one subgroup, all of one block of output channels) share each
  // step's weight texels (conv2d.comp SHARED_WEIGHTS) where the plan says so and the weights
  // are RGBA float texels (engine/kernel_plan.h, convSharedWeights).
  const bool sharedWeights = engine.plan().convSharedWeights && !quantized && rgba && tiles.localY == 1 &&
                             tiles.localX == ops::cpuLanes(caps);
  const auto kernelFor = [&](bool out4) -> const Kernel& {
    std::vector<int32_t> constants = {tiles.localX, tiles.localY, 1, int(KH), int(KW), params.stride, tiles.channels,
                                      tiles.rows, tiles.cols, G, rgba ? 4 : 1, static_cast<int>(params.act),
                                      bias.defined(), rgbaX ? 4 : 1, rgbaX ? (4 - params.padX % 4) % 4 : 0, flat};
    if (quantized) constants.push_back(w.dtype() == DType::Q8 ? 8 : 4);  // W_BITS
    if (sharedWeights) constants.insert(constants.end(), {8, tiles.localX});  // W_BITS (unused), LANES
    return engine.kernel({std::string(quantized ? "conv2d_q_f32" : sharedWeights ? "conv2d_sw_f32" : "conv2d_f32") +
                              (out4 ? "_out4" : ""),
                          {Bind::Texel, Bind::Texel, Bind::Texel, Bind::Write},
                          sizeof(ConvPush), constants, sharedWeights ? uint32_t(tiles.localX) : 0u});
  };

  // One workgroup layer per (image, block of output channels).
  const int64_t coBlocks = (Cout + tiles.channels - 1) / tiles.channels;
  const uint32_t gx = flat ? ceilDiv(colBlocks * rowBlocks, tiles.localX) : ceilDiv(colBlocks, tiles.localX);
  const uint32_t gy = flat ? 1 : ceilDiv(rowBlocks, tiles.localY);
  if (gx > caps.maxWorkGroupCount[0] || gy > caps.maxWorkGroupCount[1])
    throw Error("conv2d: output " + y.describe() + " needs more workgroups than the device allows");
  forEachUnitChunk(engine, x, y, N, Cout, tiles.channels, Ho * Wo, 1, "conv2d", [&](const UnitChunk& c) {
    const ConvPush push{int32_t(Cin),      int32_t(H),      int32_t(W),  int32_t(Cout), int32_t(Ho),
                        int32_t(Wo),       params.padY,     params.padX, int32_t(coBlocks), int32_t(c.u0),
                        c.in.base,         wr.base,         br.base,     c.out.base};
    rec.dispatch(kernelFor(rowsOf4 && c.out.base % 4 == 0),
                 {Arg::texel(c.in.view, rgbaX ? 4 : 1), Arg::texel(wr.view, wComponents),
                  // without a bias a placeholder never read: the weight, or for a quantized one
                  // (words, no float texels) one element of x
                  Arg::texel(bias.defined() || !quantized ? br.view : c.in.view.view(0, {1}), 1),
                  Arg::out(c.out.view)},
                 push, gx, gy, static_cast<uint32_t>(c.u1 - c.u0));
  });
}

}  // namespace spar
