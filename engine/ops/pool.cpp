// Host side of shaders/pool.comp.
#include "engine/ops/pool.h"

#include "engine/ops/binding_range.h"

namespace spar {
namespace {

struct PoolPush {
  int32_t C, H, W, Ho, Wo, K, cBlocks, zBase, inBase, outBase;
};

}  // namespace

void avgPool2d(Recorder& rec, const Tensor& x, const Tensor& y, int k) {
  using namespace ops;
  Engine& engine = rec.engine();
  const DeviceCaps& caps = engine.caps();
  requireF32(x, "avgPool2d", "input");
  requireF32(y, "avgPool2d", "output");
  if (k < 1) throw Error("avgPool2d: kernel size must be >= 1, got " + std::to_string(k));
  if (x.rank() != 4) throw Error("avgPool2d: input must be [N, C, H, W], got " + x.describe());
  const int64_t N = x.dim(0), C = x.dim(1), H = x.dim(2), W = x.dim(3), Ho = H / k, Wo = W / k;
  if (Ho == 0 || Wo == 0)
    throw Error("avgPool2d: kernel " + std::to_string(k) + " is larger than the input " + x.describe());
  if (y.shape() != Shape{N, C, Ho, Wo})
    throw Error("avgPool2d: output " + y.describe() + " should be " + shapeString({N, C, Ho, Wo}));
  if (y.numel() == 0) return;
  for (const Tensor* t : {&x, &y}) checkElementCount(*t, "avgPool2d");

  const int rx = 4, rc = 4;
  const int localX = engine.plan().cpuShapes ? std::max<int>(8, caps.subgroupSize) : 64;
  const Kernel& kernel =
      engine.kernel({"avg_pool2d_f32", {Bind::Texel, Bind::Write}, sizeof(PoolPush), {localX, 1, 1, rx, rc}});
  const int64_t cBlocks = (C + rc - 1) / rc;
  const uint32_t gx = ceilDiv(ceilDiv(Wo, rx), localX);
  if (Ho > caps.maxWorkGroupCount[1]) throw Error("avgPool2d: output height exceeds the device's grid");
  forEachUnitChunk(engine, x, y, N, C, rc, Ho * Wo, 1, "avgPool2d", [&](const UnitChunk& c) {
    const PoolPush push{int32_t(C),       int32_t(H),    int32_t(W), int32_t(Ho), int32_t(Wo), k, int32_t(cBlocks),
                        int32_t(c.u0),    c.in.base,     c.out.base};
    rec.dispatch(kernel, {Arg::texel(c.in.view, 1), Arg::out(c.out.view)}, push, gx, static_cast<uint32_t>(Ho),
                 static_cast<uint32_t>(c.u1 - c.u0));
  });
}

}  // namespace spar
