// Host side of shaders/im2col.comp.
#include "engine/ops/im2col.h"

#include "engine/engine.h"
#include "engine/ops/binding_range.h"
#include "engine/ops/dispatch_helpers.h"

namespace spar::ops {
namespace {

struct Im2colPush {
  int32_t Cin, H, W, Wo, KH, KW, stride, padY, padX, oy0, count, xBase;
};

}  // namespace

uint64_t im2colScratchBytes(Engine& engine) {
  return engine.plan().gemmLanesSplitK ? uint64_t(kIm2colScratchBytes) : 0;
}

void im2col(Recorder& rec, const Tensor& x, int64_t first, const Im2colBand& b, const Tensor& p) {
  Engine& engine = rec.engine();
  const DeviceCaps& caps = engine.caps();
  const int64_t image = b.Cin * b.H * b.W, count = b.rows * b.Wo * b.Cin * b.KH * b.KW;
  if (p.numel() != count) throw Error("im2col: " + p.describe() + " does not hold " + std::to_string(count) + " values");
  const BoundRange xr = bindRange(caps, x, first, first + image, true);
  const Kernel& kernel = engine.kernel({"im2col_f32", {Bind::Texel, Bind::Write}, sizeof(Im2colPush), {256, 1, 1}});
  const Im2colPush push{int32_t(b.Cin), int32_t(b.H), int32_t(b.W), int32_t(b.Wo), int32_t(b.KH), int32_t(b.KW),
                        b.stride,       b.padY,       b.padX,       int32_t(b.oy0), int32_t(count),
                        int32_t(first - xr.base)};
  const Grid g = linearGrid(caps, ceilDiv(uint64_t(count), 256), "im2col");
  rec.dispatch(kernel, {Arg::texel(xr.view, 1), Arg::out(p)}, push, g.x, g.y, 1);
}

}  // namespace spar::ops
