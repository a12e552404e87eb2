// Softmax, L2 normalization and argmax dispatch; the kernel is shaders/reduce_channels.comp.
#include "engine/ops/reduce_channels.h"

#include "engine/ops/dispatch_helpers.h"

namespace spar {
namespace {

struct ReducePush {
  uint32_t outer, C, inner;
  float eps;
};

enum class Reduce { Softmax, L2, Argmax };

struct AxisView {
  int64_t outer = 1, C = 1, inner = 1;
};

AxisView axisView(const Tensor& x, int axis, const std::string& op) {
  const int r = x.rank();
  if (r == 0) throw Error(op + ": " + x.describe() + " has no axis");
  if (axis < -r || axis >= r) throw Error(op + ": axis " + std::to_string(axis) + " out of range for " + x.describe());
  if (axis < 0) axis += r;
  AxisView v;
  for (int i = 0; i < axis; ++i) v.outer *= x.dim(i);
  v.C = x.dim(axis);
  for (int i = axis + 1; i < r; ++i) v.inner *= x.dim(i);
  return v;
}

void reduceChannels(Recorder& rec, Reduce what, const Tensor& x, const Tensor& y, int axis, float eps,
                    const std::string& op) {
  Engine& engine = rec.engine();
  ops::requireF32(x, op, "x");
  const AxisView v = axisView(x, axis, op);
  const bool argmax = what == Reduce::Argmax;
  if (argmax) {
    if (!y.defined() || y.dtype() != DType::I32) throw Error(op + ": index must be an i32 tensor");
    if (y.numel() != v.outer * v.inner)
      throw Error(op + ": index " + y.describe() + " should hold " + std::to_string(v.outer * v.inner) + " values");
  } else {
    ops::requireF32(y, op, "y");
    if (y.shape() != x.shape()) throw Error(op + ": y " + y.describe() + " should have x's shape " + x.describe());
  }
  if (v.C == 0 && argmax) throw Error(op + ": empty axis in " + x.describe());
  if (x.numel() == 0) return;
  const bool inPlace = !argmax && ops::sameMemory(x, y);
  if (!inPlace && ops::overlaps(x, y)) throw Error(op + ": y overlaps x without being x");
  const uint64_t lines = uint64_t(v.outer) * uint64_t(v.inner);
  if (lines > 0xffffffffull || x.numel() > 0x7fffffff) throw Error(op + ": too many values for 32-bit indexing");

  const bool vec4 = v.inner == 1 && v.C % 4 == 0;
  const ops::LineGroup g = ops::lineGroupFor(engine, vec4 ? v.C / 4 : v.C, v.inner == 1, int64_t(lines));
  // argmax keeps its index through shared memory: no subgroup variant.
  const std::string shader =
      std::string(what == Reduce::Softmax ? (inPlace ? "softmax_inplace" : "softmax")
                  : what == Reduce::L2    ? (inPlace ? "l2normalize_inplace" : "l2normalize")
                                          : "argmax") +
      (g.subgroup && what != Reduce::Argmax ? "_sg" : "");
  const std::vector<Bind> bindings =
      inPlace ? std::vector<Bind>{Bind::ReadWrite} : std::vector<Bind>{Bind::Read, Bind::Write};
  const Kernel& kernel = engine.kernel({shader, bindings, sizeof(ReducePush), {g.localX, g.localY, 1, g.split, vec4}});

  const int64_t xRow = v.C * v.inner, yRow = argmax ? v.inner : xRow;
  const Tensor x2 = x.reshape({v.outer, xRow}), y2 = y.reshape({v.outer, yRow});
  for (auto [o0, n] : ops::rowChunks(engine, v.outer, {uint64_t(xRow) * 4, uint64_t(yRow) * 4}, op)) {
    const Tensor xc = x2.view(o0 * xRow, {n, xRow}), yc = y2.view(o0 * yRow, {n, yRow});
    const ReducePush push{uint32_t(n), uint32_t(v.C), uint32_t(v.inner), eps};
    const ops::Grid grid = ops::linearGrid(engine.caps(), ops::ceilDiv(uint64_t(n) * v.inner, g.linesPerGroup()), op);
    rec.dispatch(kernel, inPlace ? std::vector<Arg>{Arg::inout(xc)} : std::vector<Arg>{Arg::in(xc), Arg::out(yc)}, push,
                 grid.x, grid.y, 1, op);
  }
}

}  // namespace

void softmax(Recorder& rec, const Tensor& x, const Tensor& y, int axis) {
  reduceChannels(rec, Reduce::Softmax, x, y, axis, 0.0f, "softmax");
}

void l2Normalize(Recorder& rec, const Tensor& x, const Tensor& y, int axis, float eps) {
  if (!(eps > 0.0f)) throw Error("l2Normalize: eps must be > 0");
  reduceChannels(rec, Reduce::L2, x, y, axis, eps, "l2Normalize");
}

void argmax(Recorder& rec, const Tensor& x, const Tensor& index, int axis) {
  reduceChannels(rec, Reduce::Argmax, x, index, axis, 0.0f, "argmax");
}

}  // namespace spar
