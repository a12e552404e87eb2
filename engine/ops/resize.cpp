// Host side of shaders/resize.comp.
#include "engine/ops/resize.h"

#include "engine/ops/binding_range.h"

namespace spar {
namespace {

struct ResizePush {
  int32_t C, H, W, Ho, Wo, cBlocks, zBase, inBase, outBase;
};

}  // namespace

void resizeBilinear(Recorder& rec, const Tensor& x, const Tensor& y, bool alignCorners) {
  using namespace ops;
  Engine& engine = rec.engine();
  const DeviceCaps& caps = engine.caps();
  requireF32(x, "resizeBilinear", "input");
  requireF32(y, "resizeBilinear", "output");
  if (x.rank() != 4 || y.rank() != 4)
    throw Error("resizeBilinear: input and output must be [N, C, H, W], got " + x.describe() + " and " + y.describe());
  const int64_t N = x.dim(0), C = x.dim(1), H = x.dim(2), W = x.dim(3), Ho = y.dim(2), Wo = y.dim(3);
  if (y.dim(0) != N || y.dim(1) != C)
    throw Error("resizeBilinear: output " + y.describe() + " does not match input " + x.describe());
  if (y.numel() == 0) return;
  if (H == 0 || W == 0) throw Error("resizeBilinear: empty input " + x.describe());
  // Source coordinates are computed as (2 dst + 1) * in in 32-bit integers.
  if ((2 * std::max(Ho, Wo) + 1) * std::max(H, W) >= INT32_MAX)
    throw Error("resizeBilinear: sizes " + x.describe() + " -> " + y.describe() + " are too large");
  for (const Tensor* t : {&x, &y}) checkElementCount(*t, "resizeBilinear");

  const int rx = 4, rc = 4;
  const int localX = engine.plan().cpuShapes ? std::max<int>(8, caps.subgroupSize) : 64;
  const Kernel& kernel = engine.kernel({"resize_bilinear_f32",
                                        {Bind::Texel, Bind::Write},
                                        sizeof(ResizePush),
                                        {localX, 1, 1, rx, rc, alignCorners}});
  const int64_t cBlocks = (C + rc - 1) / rc;
  const uint32_t gx = ceilDiv(ceilDiv(Wo, rx), localX);
  if (Ho > caps.maxWorkGroupCount[1]) throw Error("resizeBilinear: output height exceeds the device's grid");
  forEachUnitChunk(engine, x, y, N, C, rc, Ho * Wo, 1, "resizeBilinear", [&](const UnitChunk& c) {
    const ResizePush push{int32_t(C),  int32_t(H),       int32_t(W), int32_t(Ho), int32_t(Wo), int32_t(cBlocks),
                          int32_t(c.u0), c.in.base, c.out.base};
    rec.dispatch(kernel, {Arg::texel(c.in.view, 1), Arg::out(c.out.view)}, push, gx, static_cast<uint32_t>(Ho),
                 static_cast<uint32_t>(c.u1 - c.u0));
  });
}

}  // namespace spar
