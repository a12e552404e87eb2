// NaN / infinity counting (engine/ops/count_nonfinite.h); the kernel is
// shaders/count_nonfinite.comp.
#include "engine/ops/count_nonfinite.h"

#include "engine/ops/dispatch_helpers.h"

namespace spar {
namespace {

struct CountPush {
  uint32_t n, slot;
};

}  // namespace

void countNonFinite(Recorder& rec, const Tensor& x, const Tensor& counts, int64_t slot) {
  const std::string op = "countNonFinite";
  Engine& engine = rec.engine();
  ops::requireF32(x, op, "x");
  if (counts.dtype() != DType::I32 || counts.rank() != 1) throw Error(op + ": counts must be I32 [slots], got " + counts.describe());
  if (slot < 0 || slot >= counts.dim(0)) throw Error(op + ": slot " + std::to_string(slot) + " outside " + counts.describe());
  if (x.numel() == 0) return;
  const Kernel& kernel =
      engine.kernel({"count_nonfinite", {Bind::Read, Bind::ReadWrite}, sizeof(CountPush), {ops::elementLocalX(engine.caps()), 1, 1}});
  const Tensor flat = x.reshape({x.numel()});
  for (auto [i0, n] : ops::rowChunks(engine, x.numel(), {4}, op)) {
    const CountPush push{uint32_t(n), uint32_t(slot)};
    const ops::Grid grid = ops::linearGrid(engine.caps(), ops::ceilDiv(uint64_t(n), ops::elementsPerGroup(engine.caps())), op);
    rec.dispatch(kernel, {Arg::in(flat.view(i0, {n})), Arg::inout(counts)}, push, grid.x, grid.y, 1, op);
  }
}

}  // namespace spar
