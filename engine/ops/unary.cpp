// Elementwise unary dispatch; the kernel is shaders/unary.comp.
#include "engine/ops/unary.h"

#include "engine/ops/dispatch_helpers.h"

namespace spar {
namespace {

struct UnaryPush {
  uint32_t n;
  float alpha, beta;
};

const char* variantName(UnaryOp op, bool inPlace) {
  switch (op) {
    case UnaryOp::Gelu:
      return inPlace ? "unary_gelu_inplace" : "unary_gelu";
    case UnaryOp::QuickGelu:
      return inPlace ? "unary_quick_gelu_inplace" : "unary_quick_gelu";
    case UnaryOp::Silu:
      return inPlace ? "unary_silu_inplace" : "unary_silu";
    case UnaryOp::Sigmoid:
      return inPlace ? "unary_sigmoid_inplace" : "unary_sigmoid";
    case UnaryOp::Relu:
      return inPlace ? "unary_relu_inplace" : "unary_relu";
    case UnaryOp::Scale:
      return inPlace ? "unary_scale_inplace" : "unary_scale";
  }
  throw Error("unary: unknown op");
}

}  // namespace

void unary(Recorder& rec, UnaryOp op, const Tensor& x, const Tensor& y, float alpha, float beta) {
  const std::string name = "unary";
  Engine& engine = rec.engine();
  ops::requireF32(x, name, "x");
  ops::requireF32(y, name, "y");
  if (x.numel() != y.numel()) throw Error(name + ": x " + x.describe() + " and y " + y.describe() + " differ in size");
  const bool inPlace = ops::sameMemory(x, y);
  if (!inPlace && ops::overlaps(x, y)) throw Error(name + ": y overlaps x without being x");
  const int64_t n = x.numel();
  if (n == 0) return;

  const Kernel& kernel =
      engine.kernel({variantName(op, inPlace),
                     inPlace ? std::vector<Bind>{Bind::ReadWrite} : std::vector<Bind>{Bind::Read, Bind::Write},
                     sizeof(UnaryPush),
                     {ops::elementLocalX(engine.caps()), 1, 1}});
  const Tensor x1 = x.reshape({n}), y1 = y.reshape({n});
  for (auto [i0, count] : ops::rowChunks(engine, n, {4}, name, 4)) {
    const Tensor xc = x1.view(i0, {count}), yc = y1.view(i0, {count});
    const ops::Grid grid = ops::linearGrid(engine.caps(), ops::ceilDiv(count, ops::elementsPerGroup(engine.caps())), name);
    rec.dispatch(kernel, inPlace ? std::vector<Arg>{Arg::inout(xc)} : std::vector<Arg>{Arg::in(xc), Arg::out(yc)},
                 UnaryPush{uint32_t(count), alpha, beta}, grid.x, grid.y, 1, variantName(op, inPlace));
  }
}

void activate(Recorder& rec, Activation act, const Tensor& x, const Tensor& y) {
  switch (act) {
    case Activation::None:
      if (!ops::sameMemory(x, y)) unary(rec, UnaryOp::Scale, x, y, 1.0f, 0.0f);
      return;
    case Activation::Gelu:
      return unary(rec, UnaryOp::Gelu, x, y);
    case Activation::QuickGelu:
      return unary(rec, UnaryOp::QuickGelu, x, y);
    case Activation::Silu:
      return unary(rec, UnaryOp::Silu, x, y);
    case Activation::Sigmoid:
      return unary(rec, UnaryOp::Sigmoid, x, y);
    case Activation::Relu:
      return unary(rec, UnaryOp::Relu, x, y);
  }
  throw Error("activate: unknown activation");
}

}  // namespace spar
