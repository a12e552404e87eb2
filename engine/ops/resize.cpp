// Host side of shaders/resize.comp.
#include "engine/ops/resize.h"

#include "engine/ops/binding_range.h"

namespace spar {
namespace {

struct ResizePush {
  int32_t C, H, W, Ho, Wo, cBlocks, zBase, inBase, outBase;
};

// The checks of both ops: x [N, C, H, W] f32 to an output of Ho x Wo per image.
void checkResize(const Tensor& x, int64_t Ho, int64_t Wo, const Tensor& y, const char* op) {
  using namespace ops;
  requireF32(x, op, "input");
  if (x.rank() != 4) throw Error(std::string(op) + ": input must be [N, C, H, W], got " + x.describe());
  const int64_t H = x.dim(2), W = x.dim(3);
  if (y.numel() == 0) return;
  if (H == 0 || W == 0 || x.dim(1) == 0) throw Error(std::string(op) + ": empty input " + x.describe());
  // Source coordinates are computed as (2 dst + 1) * in in 32-bit integers.
  if ((2 * std::max(Ho, Wo) + 1) * std::max(H, W) >= INT32_MAX)
    throw Error(std::string(op) + ": sizes " + x.describe() + " -> " + y.describe() + " are too large");
  for (const Tensor* t : {&x, &y}) checkElementCount(*t, op);
}

// One kernel, two variants: resized channels (f32), or the argmax over them (i32, a work unit is
// a whole image: channel blocks of C).
void dispatchResize(Recorder& rec, const Tensor& x, const Tensor& y, int64_t Ho, int64_t Wo, bool alignCorners,
                    bool argmax, const char* op) {
  using namespace ops;
  Engine& engine = rec.engine();
  const DeviceCaps& caps = engine.caps();
  const int64_t N = x.dim(0), C = x.dim(1), H = x.dim(2), W = x.dim(3);
  const int rx = 4, rc = 4;
  const int localX = engine.plan().cpuShapes ? std::max<int>(8, caps.subgroupSize) : 64;
  const Kernel& kernel = engine.kernel({argmax ? "resize_bilinear_argmax_i32" : "resize_bilinear_f32",
                                        {Bind::Texel, Bind::Write},
                                        sizeof(ResizePush),
                                        {localX, 1, 1, rx, rc, alignCorners}});
  const int64_t blockChannels = argmax ? C : rc, outChannels = argmax ? 1 : C;
  const int64_t cBlocks = (C + blockChannels - 1) / blockChannels;
  const uint32_t gx = ceilDiv(ceilDiv(Wo, rx), localX);
  if (Ho > caps.maxWorkGroupCount[1]) throw Error(std::string(op) + ": output height exceeds the device's grid");
  // with argmax, y is [N, 1, Ho, Wo] to the chunking: one output channel per image
  forEachUnitChunk(engine, x, y, N, outChannels, argmax ? 1 : rc, Ho * Wo, 1, op, [&](const UnitChunk& c) {
    const ResizePush push{int32_t(C),  int32_t(H),       int32_t(W), int32_t(Ho), int32_t(Wo), int32_t(cBlocks),
                          int32_t(c.u0), c.in.base, c.out.base};
    rec.dispatch(kernel, {Arg::texel(c.in.view, 1), Arg::out(c.out.view)}, push, gx, static_cast<uint32_t>(Ho),
                 static_cast<uint32_t>(c.u1 - c.u0));
  });
}

}  // namespace

void resizeBilinear(Recorder& rec, const Tensor& x, const Tensor& y, bool alignCorners) {
  using namespace ops;
  requireF32(y, "resizeBilinear", "output");
  if (x.rank() != 4 || y.rank() != 4)
    throw Error("resizeBilinear: input and output must be [N, C, H, W], got " + x.describe() + " and " + y.describe());
  if (y.dim(0) != x.dim(0) || y.dim(1) != x.dim(1))
    throw Error("resizeBilinear: output " + y.describe() + " does not match input " + x.describe());
  checkResize(x, y.dim(2), y.dim(3), y, "resizeBilinear");
  if (y.numel() == 0) return;
  dispatchResize(rec, x, y, y.dim(2), y.dim(3), alignCorners, false, "resizeBilinear");
}

void resizeBilinearArgmax(Recorder& rec, const Tensor& scores, const Tensor& maps, bool alignCorners) {
  if (scores.rank() != 4 || maps.rank() != 3 || maps.dtype() != DType::I32 || maps.dim(0) != scores.dim(0))
    throw Error("resizeBilinearArgmax: scores must be f32 [N, C, H, W] and maps i32 [N, Ho, Wo], got " +
                scores.describe() + " and " + maps.describe());
  checkResize(scores, maps.dim(1), maps.dim(2), maps, "resizeBilinearArgmax");
  if (maps.numel() == 0) return;
  dispatchResize(rec, scores, maps, maps.dim(1), maps.dim(2), alignCorners, true, "resizeBilinearArgmax");
}

}  // namespace spar
