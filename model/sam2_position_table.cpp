// SAM2.1's Hiera position table (model/sam2_position_table.h); the kernel is
// model/shaders/sam2_position_table.comp.
#include "model/sam2_position_table.h"
#include "model/model_shaders.h"

#include <cmath>

#include "engine/ops/dispatch_helpers.h"

namespace spar {
namespace {

struct PositionTablePush {
  uint32_t channels, bgH, bgW, side, win;
};

}  // namespace

void sam2PositionTable(Recorder& rec, const Tensor& background, const Tensor& window, const Tensor& table) {
  const std::string op = "sam2PositionTable";
  Engine& engine = rec.engine();
  if (!background.defined() || !window.defined() || !table.defined()) throw Error(op + ": missing tensor");
  ops::requireF32(background, op, "background");
  ops::requireF32(window, op, "window");
  ops::requireF32(table, op, "table");
  if (background.rank() != 4 || background.dim(0) != 1)
    throw Error(op + ": background must be [1, C, Hb, Wb], got " + background.describe());
  const int64_t C = background.dim(1), bgH = background.dim(2), bgW = background.dim(3);
  if (window.rank() != 4 || window.dim(0) != 1 || window.dim(1) != C || window.dim(2) != window.dim(3))
    throw Error(op + ": window must be [1, " + std::to_string(C) + ", w, w], got " + window.describe());
  const int64_t win = window.dim(2);
  if (table.rank() != 2 || table.dim(1) != C)
    throw Error(op + ": table must be [side * side, " + std::to_string(C) + "], got " + table.describe());
  const int64_t side = int64_t(std::llround(std::sqrt(double(table.dim(0)))));
  if (side * side != table.dim(0)) throw Error(op + ": table rows " + std::to_string(table.dim(0)) + " are not a square");
  if (C == 0 || side == 0) return;
  if (bgH == 0 || bgW == 0 || win == 0) throw Error(op + ": empty background or window");
  if (side % win) throw Error(op + ": the window table (" + std::to_string(win) + ") does not tile " + std::to_string(side));
  if (ops::overlaps(table, background) || ops::overlaps(table, window)) throw Error(op + ": table overlaps an input");
  if (uint64_t(table.numel()) > 0x7fffffffull) throw Error(op + ": too many values for 32-bit indexing");
  if (uint64_t(table.bytes()) > engine.device().bindingRangeLimit())
    throw Error(op + ": table " + table.describe() + " exceeds one storage binding");

  registerModelShaders();  // model/shaders/sam2_position_table.comp
  const Kernel& kernel = engine.kernel({"sam2_position_table", {Bind::Read, Bind::Read, Bind::Write},
                                        sizeof(PositionTablePush), {ops::elementLocalX(engine.caps()), 1, 1}});
  const PositionTablePush push{uint32_t(C), uint32_t(bgH), uint32_t(bgW), uint32_t(side), uint32_t(win)};
  const ops::Grid grid = ops::linearGrid(
      engine.caps(), ops::ceilDiv(uint64_t(table.numel()), uint64_t(ops::elementLocalX(engine.caps()))), op);
  rec.dispatch(kernel, {Arg::in(background), Arg::in(window), Arg::out(table)}, push, grid.x, grid.y, 1, op);
}

}  // namespace spar
