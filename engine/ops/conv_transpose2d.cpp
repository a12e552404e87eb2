// Host side of shaders/conv_transpose2d.comp.
#include "engine/ops/conv_transpose2d.h"

#include <cstdio>
#include <cstdlib>

#include "engine/ops/binding_range.h"
#include "engine/ops/cpu_tiles.h"
#include "engine/ops/im2col.h"
#include "engine/ops/linear.h"

namespace spar {
namespace {

struct ConvTransposePush {
  int32_t Cin, H, W, Cout, coBlocks, zBase, inBase, wBase, biasBase, outBase;
};

// Register block (channels x input rows x input columns) and workgroup shape; the block
// holds channels * rows * cols * k * k outputs.
struct Tiles {
  int channels, rows, cols, localX, localY;
};

// cpu: the plan's CPU shapes (engine/kernel_plan.h).
Tiles chooseTiles(const DeviceCaps& caps, bool cpu, const KernelTuning& tuning, int k, double multiplyAdds) {
  // EngineOptions::tuning.convTransposeTiles (SPAR_CONVT_TILES) overrides, for tuning with
  // spar-bench --only drp_.
  if (const auto& t = tuning.convTransposeTiles) return {(*t)[0], (*t)[1], (*t)[2], (*t)[3], (*t)[4]};
  // CPU (llvmpipe): 4 input columns = one RGBA texel. Mesa 22.3: about 256-512 outputs per
  // invocation for layers of 2^26 multiply-adds and more (spar-bench's drp_*_convt, 2^27: bigger
  // blocks compile for seconds and run no faster, 64 outputs compile in 0.4 s instead of 1.4 s
  // but ran 10-15 % slower); 64 outputs for smaller layers, where the compile is most of the
  // cost. Mesa 25.0.7 compiles 3x slower and ran 64 outputs as fast: 4 channels x 1 row there,
  // 2 channels for k = 4 (4 took 4 s).
  const int lanes = ops::cpuLanes(caps);
  if (cpu && ops::cpuTiles(caps) == ops::CpuTiles::Newer) return {k > 4 ? 1 : k > 2 ? 2 : 4, 1, 4, lanes, 1};
  if (cpu && multiplyAdds < double(1 << 26)) return {k > 4 ? 1 : 4, 1, 4, lanes, 1};
  if (cpu) return {k > 4 ? 1 : 4, std::clamp(512 / (16 * k * k), 1, 4), 4, lanes, 1};
  return {2, 1, 4, 16, 8};
}

// Where the plan splits a GEMM's k among a subgroup's lanes (KernelPlan::gemmLanesSplitK,
// SwiftShader), as conv2d does (engine/ops/conv2d.cpp): with kernel = stride = k every output
// block is a product, y's k x k block at (i, j) = w^T x[:, i, j]. im2col's 1x1 patches give the
// two transposes (the kernel as [Cout k k, Cin], the input's band of rows as [pixels, Cin]) in
// the recorder's scratch, and gemm_lanes.comp scatters the products into the blocks (SCATTER_K)
// with the bias and the activation. False (nothing recorded) where they do not fit.
bool convTranspose2dAsIm2colGemm(Recorder& rec, const Tensor& x, const Tensor& w, const Tensor& bias, const Tensor& y,
                                 Activation act) {
  using namespace ops;
  Engine& engine = rec.engine();
  const DeviceCaps& caps = engine.caps();
  const int64_t N = x.dim(0), Cin = x.dim(1), H = x.dim(2), W = x.dim(3), Cout = w.dim(1), k = w.dim(2);
  const int64_t rowsOfW = Cout * k * k, image = Cin * H * W, plane = H * k * W * k;
  const int64_t room = std::min(bindingElements(engine, true), bindingElements(engine, false)) - alignmentSlack(caps, true);
  const int64_t cap = kIm2colScratchBytes / 4;
  // the transposed kernel first in the scratch, then the band's patches from an aligned start
  const int64_t kernelEnd = (rowsOfW * Cin + 255) / 256 * 256;
  const int64_t bandRows = std::min<int64_t>(H, (cap - kernelEnd) / std::max<int64_t>(1, W * Cin));
  if (kernelEnd >= cap || bandRows < 1 || image > room || rowsOfW * Cin > room || Cout * plane > room) return false;
  const Tensor scratch = rec.scratch(cap);
  const Tensor wt = scratch.view(0, {rowsOfW, Cin});
  im2col(rec, w, 0, {Cin, 1, rowsOfW, rowsOfW, 1, 1, 1, 0, 0, 0, 1}, wt);
  for (int64_t n = 0; n < N; ++n)
    for (int64_t i0 = 0; i0 < H; i0 += bandRows) {
      const int64_t rows = std::min(bandRows, H - i0), pixels = rows * W;
      const Tensor p = scratch.view(kernelEnd, {pixels, Cin});
      im2col(rec, x, n * image, {Cin, H, W, W, 1, 1, 1, 0, 0, i0, rows}, p);
      gemmLanesRowBias(rec, wt, p, bias, y.view(n * Cout * plane + i0 * k * W * k, {(Cout - 1) * plane + pixels * k * k}),
                       plane, act, int(k), W);
    }
  return true;
}

}  // namespace

void convTranspose2d(Recorder& rec, const Tensor& x, const Tensor& w, const Tensor& bias, const Tensor& y,
                     Activation act) {
  using namespace ops;
  Engine& engine = rec.engine();
  const DeviceCaps& caps = engine.caps();
  requireF32(x, "convTranspose2d", "input");
  requireF32(w, "convTranspose2d", "weight");
  requireF32(y, "convTranspose2d", "output");
  if (bias.defined()) requireF32(bias, "convTranspose2d", "bias");
  if (x.rank() != 4) throw Error("convTranspose2d: input must be [N, Cin, H, W], got " + x.describe());
  if (w.rank() != 4 || w.dim(2) != w.dim(3))
    throw Error("convTranspose2d: weight must be [Cin, Cout, k, k], got " + w.describe());
  const int64_t N = x.dim(0), Cin = x.dim(1), H = x.dim(2), W = x.dim(3);
  const int64_t Cout = w.dim(1), k = w.dim(2);
  if (w.dim(0) != Cin) throw Error("convTranspose2d: weight " + w.describe() + " does not match input " + x.describe());
  if (k < 1 || k > 8) throw Error("convTranspose2d: kernel size (= stride) must be 1..8, got " + w.describe());
  if (y.shape() != Shape{N, Cout, H * k, W * k})
    throw Error("convTranspose2d: output " + y.describe() + " should be " + shapeString({N, Cout, H * k, W * k}));
  if (bias.defined() && bias.shape() != Shape{Cout})
    throw Error("convTranspose2d: bias " + bias.describe() + " should be [" + std::to_string(Cout) + "]");
  for (const Tensor* t : {&x, &w, &y}) checkElementCount(*t, "convTranspose2d");
  if (y.numel() == 0) return;
  if (Cin == 0) throw Error("convTranspose2d: input has no channels");
  if (engine.plan().gemmLanesSplitK && convTranspose2dAsIm2colGemm(rec, x, w, bias, y, act)) return;

  const int ks = static_cast<int>(k);
  const Tiles tiles = chooseTiles(caps, engine.plan().cpuShapes, engine.options().tuning, ks, double(N) * double(Cin) * double(Cout) * double(H * W) * double(k * k));
  const BoundRange wr = bindRange(caps, w, 0, w.numel(), true);
  const BoundRange br = bias.defined() ? bindRange(caps, bias, 0, Cout, true) : wr;
  const bool rgbaW = (k * k) % 4 == 0 && wr.base % 4 == 0;
  const bool rgbaX = W % 4 == 0 && tiles.cols % 4 == 0 && x.byteOffset() % 16 == 0;
  if (uint64_t(wr.view.numel() / (rgbaW ? 4 : 1)) > ops::texelInputLimit(engine, rgbaW ? 4 : 1))
    throw Error("convTranspose2d: weight " + w.describe() + " exceeds the device's texel-buffer size");
  // Workgroups of one row of invocations walk the blocks of a plane in one flat order (unless
  // a huge plane would need more workgroups along x than the device allows: then 2-D).
  const int64_t colBlocks = ceilDiv(W, tiles.cols), rowBlocks = ceilDiv(H, tiles.rows);
  const bool flat = tiles.localY == 1 && ceilDiv(colBlocks * rowBlocks, tiles.localX) <= caps.maxWorkGroupCount[0];
  // Outputs as whole vec4s (the _out4 variant) when every block row segment is: its start
  // (a multiple of cols*k in a row of W*k) and the binding's base on a 4-element boundary.
  const bool rowsOf4 = (tiles.cols * k) % 4 == 0 && (W * k) % 4 == 0;
  const auto kernelFor = [&](bool out4) -> const Kernel& {
    return engine.kernel({out4 ? "conv_transpose2d_f32_out4" : "conv_transpose2d_f32",
                          {Bind::Texel, Bind::Texel, Bind::Texel, Bind::Write},
                          sizeof(ConvTransposePush),
                          {tiles.localX, tiles.localY, 1, ks, tiles.channels, tiles.rows, tiles.cols, rgbaW ? 4 : 1,
                           rgbaX ? 4 : 1, static_cast<int>(act), bias.defined(), flat}});
  };

  // One workgroup layer per (image, block of output channels).
  const int64_t coBlocks = (Cout + tiles.channels - 1) / tiles.channels;
  const uint32_t gx = flat ? ceilDiv(colBlocks * rowBlocks, tiles.localX) : ceilDiv(colBlocks, tiles.localX);
  const uint32_t gy = flat ? 1 : ceilDiv(rowBlocks, tiles.localY);
  if (gx > caps.maxWorkGroupCount[0] || gy > caps.maxWorkGroupCount[1])
    throw Error("convTranspose2d: output " + y.describe() + " needs more workgroups than the device allows");
  forEachUnitChunk(engine, x, y, N, Cout, tiles.channels, H * k * W * k, 1, "convTranspose2d", [&](const UnitChunk& c) {
    const ConvTransposePush push{int32_t(Cin), int32_t(H), int32_t(W), int32_t(Cout), int32_t(coBlocks),
                                 int32_t(c.u0), c.in.base, wr.base,   br.base,       c.out.base};
    rec.dispatch(kernelFor(rowsOf4 && c.out.base % 4 == 0),
                 {Arg::texel(c.in.view, rgbaX ? 4 : 1), Arg::texel(wr.view, rgbaW ? 4 : 1), Arg::texel(br.view, 1),
                  Arg::out(c.out.view)},
                 push, gx, gy, static_cast<uint32_t>(c.u1 - c.u0));
  });
}

}  // namespace spar
