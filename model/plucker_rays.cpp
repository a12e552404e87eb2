// Plücker rays (model/plucker_rays.h); the kernel is model/shaders/plucker_rays.comp.
#include "model/plucker_rays.h"
#include "model/model_shaders.h"

#include "engine/ops/dispatch_helpers.h"

namespace spar {
namespace {

struct PluckerPush {
  uint32_t views, height, width;
};

}  // namespace

void pluckerRays(Recorder& rec, const Tensor& c2w, const Tensor& fxfycxcy, const Tensor& rays) {
  const std::string op = "pluckerRays";
  Engine& engine = rec.engine();
  if (!c2w.defined() || !fxfycxcy.defined() || !rays.defined()) throw Error(op + ": missing tensor");
  ops::requireF32(c2w, op, "c2w");
  ops::requireF32(fxfycxcy, op, "fxfycxcy");
  ops::requireF32(rays, op, "rays");
  if (c2w.rank() < 2 || c2w.dim(-1) != 4 || c2w.dim(-2) != 4)
    throw Error(op + ": c2w must be [..., 4, 4], got " + c2w.describe());
  const int64_t V = c2w.numel() / 16;
  if (fxfycxcy.dim(-1) != 4 || fxfycxcy.numel() != V * 4)
    throw Error(op + ": fxfycxcy " + fxfycxcy.describe() + " should be [" + std::to_string(V) + ", 4]");
  if (rays.rank() < 3 || rays.dim(-3) != 6)
    throw Error(op + ": rays must be [..., 6, H, W], got " + rays.describe());
  const int64_t H = rays.dim(-2), W = rays.dim(-1);
  if (rays.numel() != V * 6 * H * W)
    throw Error(op + ": rays " + rays.describe() + " does not hold " + std::to_string(V) + " views");
  if (ops::overlaps(rays, c2w) || ops::overlaps(rays, fxfycxcy)) throw Error(op + ": rays overlap an input");
  if (V == 0 || H == 0 || W == 0) return;
  if (uint64_t(rays.numel()) > 0x7fffffffull) throw Error(op + ": too many values for 32-bit indexing");
  if (uint64_t(rays.bytes()) > engine.device().bindingRangeLimit())
    throw Error(op + ": rays " + rays.describe() + " exceed one storage binding");

  registerModelShaders();  // model/shaders/plucker_rays.comp
  const Kernel& kernel = engine.kernel(
      {"plucker_rays", {Bind::Read, Bind::Read, Bind::Write}, sizeof(PluckerPush), {ops::elementLocalX(engine.caps()), 1, 1}});
  const PluckerPush push{uint32_t(V), uint32_t(H), uint32_t(W)};
  const ops::Grid grid =
      ops::linearGrid(engine.caps(), ops::ceilDiv(uint64_t(V * H * W), uint64_t(ops::elementLocalX(engine.caps()))), op);
  rec.dispatch(kernel, {Arg::in(c2w), Arg::in(fxfycxcy), Arg::out(rays)}, push, grid.x, grid.y, 1, op);
}

}  // namespace spar
