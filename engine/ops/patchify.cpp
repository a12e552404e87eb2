// Host side of shaders/patchify.comp.
#include "engine/ops/patchify.h"

#include "engine/ops/binding_range.h"

namespace spar {
namespace {

struct PatchifyPush {
  int32_t C, H, W, P, zBase, inBase, outBase;
};

void patchCopy(Recorder& rec, const Tensor& images, const Tensor& tokens, int p, bool toTokens) {
  using namespace ops;
  const char* op = toTokens ? "patchify" : "unpatchify";
  Engine& engine = rec.engine();
  const DeviceCaps& caps = engine.caps();
  requireF32(images, op, "image");
  requireF32(tokens, op, "token");
  if (images.rank() != 4) throw Error(std::string(op) + ": images must be [V, C, H, W], got " + images.describe());
  if (p < 1) throw Error(std::string(op) + ": patch size must be >= 1, got " + std::to_string(p));
  const int64_t V = images.dim(0), C = images.dim(1), H = images.dim(2), W = images.dim(3);
  if (H % p || W % p)
    throw Error(std::string(op) + ": image size " + std::to_string(H) + "x" + std::to_string(W) +
                " is not a multiple of the patch size " + std::to_string(p));
  const int64_t T = (H / p) * (W / p), F = int64_t(p) * p * C;
  if (tokens.shape() != Shape{V, T, F})
    throw Error(std::string(op) + ": tokens " + tokens.describe() + " should be " + shapeString({V, T, F}) +
                " for images " + images.describe() + " and patch size " + std::to_string(p));
  for (const Tensor* t : {&images, &tokens}) checkElementCount(*t, op);
  if (images.numel() == 0) return;

  // 16 outputs per invocation: on llvmpipe smaller blocks pay more per-workgroup overhead
  // than the copy itself.
  const int rx = engine.plan().cpuShapes ? 16 : 4;
  const int localX = engine.plan().cpuShapes ? std::max<int>(8, caps.subgroupSize) : 64;
  const Kernel& kernel = engine.kernel({toTokens ? "patchify_f32" : "unpatchify_f32",
                                        {Bind::Texel, Bind::Write},
                                        sizeof(PatchifyPush),
                                        {localX, 1, 1, rx}});
  // Work units: images (patchify) or (image, channel) planes (unpatchify), one workgroup layer each.
  const Tensor& in = toTokens ? images : tokens;
  const Tensor& out = toTokens ? tokens : images;
  const int64_t rows = toTokens ? T : H, cols = toTokens ? F : W;
  if (rows > caps.maxWorkGroupCount[1]) throw Error(std::string(op) + ": " + out.describe() + " exceeds the device's grid");
  const uint32_t gx = ceilDiv(ceilDiv(cols, rx), localX);
  forEachUnitChunk(engine, in, out, V, toTokens ? 1 : C, 1, toTokens ? T * F : H * W, 1, op, [&](const UnitChunk& c) {
    const PatchifyPush push{int32_t(C), int32_t(H), int32_t(W), p, int32_t(c.u0), c.in.base, c.out.base};
    rec.dispatch(kernel, {Arg::texel(c.in.view, 1), Arg::out(c.out.view)}, push, gx, static_cast<uint32_t>(rows),
                 static_cast<uint32_t>(c.u1 - c.u0));
  });
}

}  // namespace

void patchify(Recorder& rec, const Tensor& images, const Tensor& tokens, int p) {
  patchCopy(rec, images, tokens, p, true);
}

void unpatchify(Recorder& rec, const Tensor& tokens, const Tensor& images, int p) {
  patchCopy(rec, images, tokens, p, false);
}

}  // namespace spar
