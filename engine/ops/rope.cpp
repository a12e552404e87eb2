// RoPE dispatch; the kernel is shaders/rope.comp.
#include "engine/ops/rope.h"

#include "engine/ops/dispatch_helpers.h"

namespace spar {
namespace {

struct RopePush {
  uint32_t items, rotated, prefix, tokens, stride, heads2, dh, units;
};

constexpr int kLocalX = 64;

}  // namespace

void rope(Recorder& rec, const Tensor& qkv, int64_t heads, int64_t headDim, int64_t prefix, const Tensor& sin,
          const Tensor& cos) {
  const std::string op = "rope";
  Engine& engine = rec.engine();
  ops::requireF32(qkv, op, "qkv");
  ops::requireF32(sin, op, "sin");
  ops::requireF32(cos, op, "cos");
  if (qkv.rank() != 3) throw Error(op + ": qkv must be [B, N, C], got " + qkv.describe());
  if (heads < 0 || headDim < 2 || headDim % 2)
    throw Error(op + ": need heads >= 0 and an even head dim, got " + std::to_string(heads) + " x " +
                std::to_string(headDim));
  const int64_t B = qkv.dim(0), N = qkv.dim(1), C = qkv.dim(2), D = heads * headDim;
  if (2 * D > C)
    throw Error(op + ": q and k of " + std::to_string(heads) + " heads of " + std::to_string(headDim) +
                " do not fit qkv " + qkv.describe());
  if (prefix < 0 || prefix > N)
    throw Error(op + ": prefix " + std::to_string(prefix) + " out of range for " + qkv.describe());
  const int64_t rotated = N - prefix;
  const Shape table{rotated, headDim};
  if (sin.shape() != table || cos.shape() != table)
    throw Error(op + ": sin " + sin.describe() + " and cos " + cos.describe() + " should be " + shapeString(table));
  if (ops::overlaps(qkv, sin) || ops::overlaps(qkv, cos)) throw Error(op + ": the tables overlap qkv");
  if (B == 0 || rotated == 0 || heads == 0) return;
  if (N * C > 0x7fffffffll || rotated * headDim > 0x7fffffffll)
    throw Error(op + ": " + qkv.describe() + " has too many values per sequence for 32-bit indexing");

  // vec4 units need whole vec4s: 4 | dh/2 puts both halves of every head on vec4 boundaries
  // when rows and every binding start do too.
  const bool vec4 = (headDim / 2) % 4 == 0 && C % 4 == 0 && qkv.byteOffset() % 16 == 0 &&
                    sin.byteOffset() % 16 == 0 && cos.byteOffset() % 16 == 0;
  const int64_t units = headDim / 2 / (vec4 ? 4 : 1);
  const Kernel& kernel = engine.kernel(
      {"rope_f32", {Bind::ReadWrite, Bind::Read, Bind::Read}, sizeof(RopePush), {kLocalX, 1, 1, vec4}});
  const Tensor flat = qkv.reshape({B * N * C});
  // Whole sequences per dispatch, as many as one binding holds.
  for (auto [b0, count] : ops::rowChunks(engine, B, {uint64_t(N * C) * 4}, op)) {
    const uint64_t items = uint64_t(count) * rotated * 2 * heads * units;
    if (items > 0xffffffffull) throw Error(op + ": too many values for 32-bit indexing");
    const RopePush push{uint32_t(items),   uint32_t(rotated),   uint32_t(prefix), uint32_t(N),
                        uint32_t(C),       uint32_t(2 * heads), uint32_t(headDim), uint32_t(units)};
    const ops::Grid grid = ops::linearGrid(engine.caps(), ops::ceilDiv(items, kLocalX), op);
    rec.dispatch(kernel, {Arg::inout(flat.view(b0 * N * C, {count * N * C})), Arg::in(sin), Arg::in(cos)}, push, grid.x,
                 grid.y, 1, op);
  }
}

}  // namespace spar
