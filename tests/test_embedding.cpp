// Embedding lookup (shaders/embedding.comp via engine/ops/embedding.cpp): exact row copies
// from f32 and f16 tables, q8 / q4 tables dequantized, repeated ids, ids outside the table
// (zero rows), odd widths.
#include "engine/ops/embedding.h"

#include <cstring>

#include "model/quantized_matrices.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

std::vector<float> gatherRef(const std::vector<float>& table, int64_t V, int64_t D, const std::vector<int32_t>& ids) {
  std::vector<float> out;
  for (int32_t id : ids)
    for (int64_t d = 0; d < D; ++d) out.push_back(id >= 0 && id < V ? table[size_t(id * D + d)] : 0.0f);
  return out;
}

Tensor idTensor(Engine& engine, const std::vector<int32_t>& ids) {
  const Tensor t = engine.tensor({int64_t(ids.size())}, DType::I32);
  engine.write(t, ids.data(), ids.size() * sizeof(int32_t));
  return t;
}

void check(Engine& engine, int64_t V, int64_t D, DType dtype, const std::vector<int32_t>& ids) {
  std::vector<float> table = randomUniform(size_t(V * D), -3, 3, 211);
  if (dtype == DType::F16) table = roundToHalf(table);
  const Tensor t = engine.fromFloats({V, D}, table, dtype);
  GuardedOutput out(engine, {int64_t(ids.size()), D});
  Recorder rec(engine);
  embedding(rec, t, idTensor(engine, ids), out.tensor());
  rec.run();
  EXPECT_EQ(out.read(), gatherRef(table, V, D, ids));
}

TEST_F(EngineTest, EmbeddingF32OddWidth) { check(eng(), 61, 7, DType::F32, {0, 60, 5, 5, 17, 0, 33}); }
TEST_F(EngineTest, EmbeddingF16) {  // an fp16 table read as fp16 texels or as halves in words
  if (!eng().readsFp16Inputs()) GTEST_SKIP() << "device without fp16 inputs";
  check(eng(), 257, 64, DType::F16, {256, 1, 2, 3, 128, 1});
}
// A quantized table (CLIP's token embedding under q8 / q4, model/quantized_matrices.h): each row
// dequantized exactly as code * scale (the row layout quantizeRows makes), invalid ids zero.
TEST_F(EngineTest, EmbeddingQuantizedTable) {
  const int64_t V = 37, D = 96;
  const std::vector<float> table = randomUniform(size_t(V * D), -3, 3, 213);
  const std::vector<int32_t> ids = {36, 0, 5, 5, -1, 37, 20};
  for (DType q : {DType::Q8, DType::Q4}) {
    SCOPED_TRACE(dtypeName(q));
    const std::vector<uint8_t> rows = quantizeRows(table, V, D, q);
    const Tensor t = eng().tensor({V, D}, q);
    eng().write(t, rows.data(), rows.size());
    const int bits = q == DType::Q8 ? 8 : 4;
    const size_t codeBytes = size_t(D) * size_t(bits) / 8, rowBytes = codeBytes + size_t(D) / 8;
    std::vector<float> values(table.size());
    for (int64_t v = 0; v < V; ++v)
      for (int64_t d = 0; d < D; ++d) {
        const uint8_t* row = rows.data() + size_t(v) * rowBytes;
        float scale;
        std::memcpy(&scale, row + codeBytes + size_t(d / 32) * 4, 4);
        const int code = bits == 8 ? int(int8_t(row[d])) : int((row[d / 2] >> (4 * (d & 1))) & 0xF) - 8;
        values[size_t(v * D + d)] = float(code) * scale;
      }
    GuardedOutput out(eng(), {int64_t(ids.size()), D});
    Recorder rec(eng());
    embedding(rec, t, idTensor(eng(), ids), out.tensor());
    rec.run();
    EXPECT_EQ(out.read(), gatherRef(values, V, D, ids));
  }
}
TEST_F(EngineTest, EmbeddingInvalidIdsGiveZeros) { check(eng(), 61, 9, DType::F32, {-1, 61, 3, 1000000, 60}); }
TEST_F(EngineTest, EmbeddingManyTokens) {
  std::vector<int32_t> ids(1000);
  for (size_t i = 0; i < ids.size(); ++i) ids[i] = int32_t((i * 7919) % 257);
  check(eng(), 257, 33, DType::F32, ids);
}
// A table view that does not start at an aligned offset (rows picked from a later slice).
TEST_F(EngineTest, EmbeddingUnalignedTableView) {
  const int64_t V = 31, D = 5;
  const std::vector<float> all = randomUniform(size_t((V + 1) * D), -1, 1, 212);
  const Tensor whole = eng().fromFloats({(V + 1) * D}, all);
  const Tensor table = whole.view(D, {V, D});  // starts 5 floats in: not 16-byte aligned
  const std::vector<int32_t> ids = {0, 30, 7};
  GuardedOutput out(eng(), {3, D});
  Recorder rec(eng());
  embedding(rec, table, idTensor(eng(), ids), out.tensor());
  rec.run();
  EXPECT_EQ(out.read(), gatherRef(std::vector<float>(all.begin() + D, all.end()), V, D, ids));
}
TEST_F(EngineTest, EmbeddingRefusesBadShapes) {
  const Tensor t = eng().tensor({4, 3});
  const Tensor ids = idTensor(eng(), {0, 1});
  Recorder rec(eng());
  EXPECT_THROW(embedding(rec, t, ids, eng().tensor({2, 4})), Error);
  EXPECT_THROW(embedding(rec, t, eng().tensor({2}), eng().tensor({2, 3})), Error);
}

}  // namespace
}  // namespace spar::test
