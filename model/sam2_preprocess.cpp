// SAM2.1's image pre-processing (model/sam2_preprocess.h); the kernel is
// model/shaders/sam2_preprocess.comp.
#include "model/sam2_preprocess.h"
#include "model/model_shaders.h"

#include "engine/ops/dispatch_helpers.h"

namespace spar {
namespace {

struct PreprocessPush {
  uint32_t height, width, outH, outW, imageOffset;
};

}  // namespace

void sam2Preprocess(Recorder& rec, const Tensor& images, int64_t view, const Tensor& out) {
  const std::string op = "sam2Preprocess";
  Engine& engine = rec.engine();
  if (!images.defined() || !out.defined()) throw Error(op + ": missing tensor");
  ops::requireF32(images, op, "images");
  ops::requireF32(out, op, "out");
  if (images.rank() != 4 || images.dim(1) != 3) throw Error(op + ": images must be [V, 3, H, W], got " + images.describe());
  if (view < 0 || view >= images.dim(0))
    throw Error(op + ": view " + std::to_string(view) + " is outside the " + std::to_string(images.dim(0)) + " images");
  if (out.rank() != 3 || out.dim(0) != 3) throw Error(op + ": out must be [3, S, S], got " + out.describe());
  const int64_t H = images.dim(2), W = images.dim(3), outH = out.dim(1), outW = out.dim(2);
  if (H == 0 || W == 0 || outH == 0 || outW == 0) throw Error(op + ": empty image or output");
  if (outH < H || outW < W)
    throw Error(op + ": " + std::to_string(H) + "x" + std::to_string(W) + " images are larger than SAM2's " +
                std::to_string(outH) + "x" + std::to_string(outW) + " input (only upsampling is supported)");
  if (ops::overlaps(out, images)) throw Error(op + ": out overlaps the images");
  if (uint64_t(images.numel()) > 0x7fffffffull || uint64_t(out.numel()) > 0x7fffffffull)
    throw Error(op + ": too many values for 32-bit indexing");
  if (uint64_t(out.bytes()) > engine.device().bindingRangeLimit() ||
      uint64_t(images.bytes()) > engine.device().bindingRangeLimit())
    throw Error(op + ": a tensor exceeds one storage binding");

  registerModelShaders();  // model/shaders/sam2_preprocess.comp
  const Kernel& kernel = engine.kernel(
      {"sam2_preprocess", {Bind::Read, Bind::Write}, sizeof(PreprocessPush), {ops::elementLocalX(engine.caps()), 1, 1}});
  const PreprocessPush push{uint32_t(H), uint32_t(W), uint32_t(outH), uint32_t(outW), uint32_t(view * 3 * H * W)};
  const ops::Grid grid =
      ops::linearGrid(engine.caps(), ops::ceilDiv(uint64_t(out.numel()), uint64_t(ops::elementLocalX(engine.caps()))), op);
  rec.dispatch(kernel, {Arg::in(images), Arg::out(out)}, push, grid.x, grid.y, 1, op);
}

}  // namespace spar
