// Pose head (model/pose_head.h); the kernel is model/shaders/pose_head.comp.
#include "model/pose_head.h"
#include "model/model_shaders.h"

#include "engine/ops/dispatch_helpers.h"

namespace spar {
namespace {

struct PoseHeadPush {
  uint32_t batch, views, canonical;
};

}  // namespace

void poseHead(Recorder& rec, const Tensor& rel, const Tensor& kraw, const Tensor& c2w, const Tensor& fxfycxcy,
              int64_t canonical) {
  const std::string op = "poseHead";
  Engine& engine = rec.engine();
  if (!kraw.defined() || !c2w.defined() || !fxfycxcy.defined()) throw Error(op + ": missing tensor");
  ops::requireF32(kraw, op, "kraw");
  ops::requireF32(c2w, op, "c2w");
  ops::requireF32(fxfycxcy, op, "fxfycxcy");
  if (c2w.rank() != 4 || c2w.dim(2) != 4 || c2w.dim(3) != 4)
    throw Error(op + ": c2w must be [B, V, 4, 4], got " + c2w.describe());
  const int64_t B = c2w.dim(0), V = c2w.dim(1);
  if (fxfycxcy.rank() != 3 || fxfycxcy.dim(0) != B || fxfycxcy.dim(1) != V || fxfycxcy.dim(2) != 4)
    throw Error(op + ": fxfycxcy " + fxfycxcy.describe() + " should be [B, V, 4] like c2w " + c2w.describe());
  if (kraw.numel() != B || (kraw.rank() != 1 && !(kraw.rank() == 2 && kraw.dim(1) == 1)))
    throw Error(op + ": kraw " + kraw.describe() + " should be [B] or [B, 1], B = " + std::to_string(B));
  if (canonical < 0 || canonical >= std::max<int64_t>(V, 1))
    throw Error(op + ": canonical view " + std::to_string(canonical) + " outside " + std::to_string(V) + " views");
  const bool hasRel = V > 1;
  if (hasRel) {
    if (!rel.defined()) throw Error(op + ": rel is missing");
    ops::requireF32(rel, op, "rel");
    if (rel.rank() != 3 || rel.dim(0) != B || rel.dim(1) != V - 1 || rel.dim(2) != 9)
      throw Error(op + ": rel " + rel.describe() + " should be [" + std::to_string(B) + ", " + std::to_string(V - 1) +
                  ", 9]");
  }
  for (const Tensor* in : {&rel, &kraw})
    if (ops::overlaps(*in, c2w) || ops::overlaps(*in, fxfycxcy)) throw Error(op + ": an output overlaps an input");
  if (ops::overlaps(c2w, fxfycxcy)) throw Error(op + ": c2w and fxfycxcy overlap");
  if (B == 0 || V == 0) return;

  registerModelShaders();  // model/shaders/pose_head.comp
  const Kernel& kernel = engine.kernel({"pose_head",
                                        {Bind::Read, Bind::Read, Bind::Write, Bind::Write},
                                        sizeof(PoseHeadPush),
                                        {64, 1, 1}});
  const PoseHeadPush push{uint32_t(B), uint32_t(V), uint32_t(canonical)};
  // Without relative views the kernel never reads rel: bind kraw in its place.
  const Tensor relArg = hasRel ? rel : kraw;
  rec.dispatch(kernel, {Arg::in(relArg), Arg::in(kraw), Arg::out(c2w), Arg::out(fxfycxcy)}, push,
               static_cast<uint32_t>(ops::ceilDiv(uint64_t(B * V), uint64_t(64))), 1, 1, op);
}

}  // namespace spar
