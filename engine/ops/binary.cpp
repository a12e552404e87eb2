// Elementwise add / multiply dispatch; the kernel is shaders/binary.comp.
#include "engine/ops/binary.h"

#include "engine/ops/binding_range.h"
#include "engine/ops/dispatch_helpers.h"

namespace spar {
namespace {

struct BinaryPush {
  uint32_t n, bInner, bSize, bPhase;
};

// bInner of b broadcast to a by NumPy rules, when b's repeated block is one contiguous run.
int64_t broadcastInner(const Tensor& a, const Tensor& b, const std::string& op) {
  const std::string fail = op + ": cannot broadcast " + b.describe() + " to " + a.describe();
  if (b.numel() == a.numel()) return 1;
  if (b.rank() > a.rank()) throw Error(fail);
  const int offset = a.rank() - b.rank();
  int first = -1, last = -1;  // dimensions of a (index) where b has a's extent (> 1)
  for (int i = 0; i < b.rank(); ++i) {
    const int64_t bd = b.dim(i), ad = a.dim(i + offset);
    if (bd == ad && bd != 1) {
      if (first < 0) first = i + offset;
      last = i + offset;
    } else if (bd != 1) {
      throw Error(fail);
    }
  }
  if (first < 0) return a.numel();  // b is a single value
  for (int i = first; i <= last; ++i)
    if (a.dim(i) != 1 && (i - offset < 0 || b.dim(i - offset) != a.dim(i))) throw Error(fail + " (repeats inside b)");
  int64_t inner = 1;
  for (int i = last + 1; i < a.rank(); ++i) inner *= a.dim(i);
  return inner;
}

void binaryOp(Recorder& rec, BinaryOp op, const Tensor& a0, const Tensor& b0, const Tensor& out, int64_t bInner,
              const std::string& name) {
  Engine& engine = rec.engine();
  ops::requireF32(a0, name, "a");
  ops::requireF32(b0, name, "b");
  ops::requireF32(out, name, "out");
  if (out.numel() != a0.numel()) throw Error(name + ": out " + out.describe() + " should match a " + a0.describe());
  Tensor a = a0, b = b0;
  // out aliasing b of the same size: both ops commute, so swap and run in place on b.
  if (!ops::sameMemory(a, out) && ops::sameMemory(b, out) && b.numel() == a.numel() && bInner == 1) std::swap(a, b);
  const bool inPlace = ops::sameMemory(a, out);
  if (!inPlace && ops::overlaps(a, out)) throw Error(name + ": out overlaps a without being a");
  if (ops::overlaps(b, out)) throw Error(name + ": out overlaps b");
  const int64_t n = a.numel(), bSize = b.numel();
  if (n == 0) return;
  if (bSize == 0 || bInner <= 0) throw Error(name + ": empty b " + b.describe());
  if (b.bytes() > engine.device().bindingRangeLimit())
    throw Error(name + ": b " + b.describe() + " exceeds one storage binding");
  const uint64_t period = uint64_t(bInner) * uint64_t(bSize);
  if (n > 0x7fffffff || period > 0x7fffffff) throw Error(name + ": too many values for 32-bit indexing");

  const bool add = op == BinaryOp::Add;
  const char* variant =
      add ? (inPlace ? "binary_add_inplace" : "binary_add") : (inPlace ? "binary_mul_inplace" : "binary_mul");
  // How a vec4 of a finds its 4 values of b (chunks start at multiples of 4, so bPhase keeps these).
  const int bMode = bInner == 1 && bSize % 4 == 0 ? 2 : bInner % 4 == 0 ? 1 : 0;
  const Kernel& kernel = engine.kernel({variant,
                                        inPlace ? std::vector<Bind>{Bind::ReadWrite, Bind::Read}
                                                : std::vector<Bind>{Bind::Read, Bind::Read, Bind::Write},
                                        sizeof(BinaryPush),
                                        {ops::elementLocalX(engine.caps()), 1, 1, bMode}});
  // b is bound whole: a view into the middle of a tensor (one row of an embedding table) may
  // start where a device with 256-byte alignment cannot bind; then a copy of it that can.
  const Tensor a1 = a.reshape({n}), o1 = out.reshape({n}), b1 = ops::alignedInput(rec, b, false).reshape({bSize});
  for (auto [i0, count] : ops::rowChunks(engine, n, {4}, name, 4)) {
    const Tensor ac = a1.view(i0, {count}), oc = o1.view(i0, {count});
    const BinaryPush push{uint32_t(count), uint32_t(bInner), uint32_t(bSize), uint32_t(uint64_t(i0) % period)};
    const ops::Grid grid = ops::linearGrid(engine.caps(), ops::ceilDiv(count, ops::elementsPerGroup(engine.caps())), name);
    rec.dispatch(kernel,
                 inPlace ? std::vector<Arg>{Arg::inout(ac), Arg::in(b1)}
                         : std::vector<Arg>{Arg::in(ac), Arg::in(b1), Arg::out(oc)},
                 push, grid.x, grid.y, 1, variant);
  }
}

}  // namespace

void binary(Recorder& rec, BinaryOp op, const Tensor& a, const Tensor& b, const Tensor& out, int64_t bInner) {
  binaryOp(rec, op, a, b, out, bInner, op == BinaryOp::Add ? "add" : "mul");
}

void add(Recorder& rec, const Tensor& a, const Tensor& b, const Tensor& out) {
  binaryOp(rec, BinaryOp::Add, a, b, out, broadcastInner(a, b, "add"), "add");
}

void mul(Recorder& rec, const Tensor& a, const Tensor& b, const Tensor& out) {
  binaryOp(rec, BinaryOp::Mul, a, b, out, broadcastInner(a, b, "mul"), "mul");
}

}  // namespace spar
