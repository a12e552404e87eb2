// Host side of shaders/embedding.comp.
#include "engine/ops/embedding.h"

#include "engine/ops/binding_range.h"
#include "engine/ops/dispatch_helpers.h"

namespace spar {
namespace {

struct EmbeddingPush {
  int32_t tokens, dim, vocab, rowBegin, rowCount, tableBase, zeroInvalid;
};

}  // namespace

void embedding(Recorder& rec, const Tensor& table, const Tensor& ids, const Tensor& out) {
  const std::string op = "embedding";
  Engine& engine = rec.engine();
  const DeviceCaps& caps = engine.caps();
  if (!table.defined() || table.rank() != 2 || table.dtype() == DType::I32)
    throw Error(op + ": table must be f32, f16, q8 or q4 [V, D], got " + (table.defined() ? table.describe() : "(none)"));
  if (!ids.defined() || ids.dtype() != DType::I32)
    throw Error(op + ": ids must be i32, got " + (ids.defined() ? ids.describe() : "(none)"));
  ops::requireF32(out, op, "out");
  const int64_t V = table.dim(0), D = table.dim(1), T = ids.numel();
  if (out.numel() != T * D)
    throw Error(op + ": out " + out.describe() + " should hold " + std::to_string(T) + " x " + std::to_string(D) + " values");
  if (T == 0 || D == 0) return;
  if (V == 0) throw Error(op + ": empty table");
  for (const Tensor* t : {&table, &out}) ops::checkElementCount(*t, op.c_str());
  if (out.bytes() > engine.device().bindingRangeLimit()) throw Error(op + ": out " + out.describe() + " exceeds one binding");

  if (isQuantized(table.dtype())) {  // bound whole, as words (shaders/quant.glsl)
    if (table.bytes() / 4 > ops::texelInputLimit(engine, 1))
      throw Error(op + ": quantized table " + table.describe() + " exceeds one binding");
    const Kernel& kernel = engine.kernel({"embedding_q_f32", {Bind::Texel, Bind::Read, Bind::Write}, sizeof(EmbeddingPush),
                                          {ops::elementLocalX(engine.caps()), 1, 1, table.dtype() == DType::Q8 ? 8 : 4}});
    const ops::Grid grid = ops::linearGrid(caps, ops::ceilDiv(uint64_t(T * D), ops::elementLocalX(engine.caps())), op);
    const EmbeddingPush push{int32_t(T), int32_t(D), int32_t(V), 0, int32_t(V), 0, 1};
    rec.dispatch(kernel, {Arg::texel(table, 1), Arg::in(ids), Arg::out(out)}, push, grid.x, grid.y, 1, op);
    return;
  }

  // Row ranges of the table that fit one texel binding whose start is aligned for the device.
  const uint64_t es = dtypeSize(table.dtype());
  const uint64_t align = std::max<uint64_t>(es, ops::bindingAlignment(caps, true));
  const int64_t slack = static_cast<int64_t>(align / es);
  const int64_t rowsPerBinding = (ops::bindingElements(engine, true) - slack) / D;
  if (rowsPerBinding < 1) throw Error(op + ": one table row exceeds a texel binding");

  const Kernel& kernel =
      engine.kernel({"embedding", {Bind::Texel, Bind::Read, Bind::Write}, sizeof(EmbeddingPush), {ops::elementLocalX(engine.caps()), 1, 1}});
  const ops::Grid grid = ops::linearGrid(caps, ops::ceilDiv(uint64_t(T * D), ops::elementLocalX(engine.caps())), op);
  for (int64_t r0 = 0; r0 < V; r0 += rowsPerBinding) {
    const int64_t n = std::min(rowsPerBinding, V - r0);
    const uint64_t beginByte = table.byteOffset() + uint64_t(r0 * D) * es;
    const uint64_t startByte = beginByte / align * align;
    const int64_t base = static_cast<int64_t>((beginByte - startByte) / es);
    const Tensor view(table.bufferPtr(), startByte, {base + n * D}, table.dtype());
    const EmbeddingPush push{int32_t(T), int32_t(D), int32_t(V), int32_t(r0), int32_t(n), int32_t(base), r0 == 0};
    rec.dispatch(kernel, {Arg::texel(view, 1), Arg::in(ids), Arg::out(out)}, push, grid.x, grid.y, 1, op);
  }
}

}  // namespace spar
