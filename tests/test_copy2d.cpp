// Strided copies, concatenation and slicing (shaders/copy2d.comp via engine/ops/copy2d.cpp):
// exact copies, checked element by element.
#include "engine/ops/copy2d.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

// torch.cat along `axis` of row-major tensors.
std::vector<float> concatRef(const std::vector<std::vector<float>>& parts, const std::vector<Shape>& shapes, int axis) {
  int64_t outer = 1, inner = 1;
  for (int i = 0; i < axis; ++i) outer *= shapes[0][i];
  for (size_t i = axis + 1; i < shapes[0].size(); ++i) inner *= shapes[0][i];
  std::vector<float> out;
  for (int64_t o = 0; o < outer; ++o)
    for (size_t p = 0; p < parts.size(); ++p) {
      const int64_t block = shapes[p][axis] * inner;
      out.insert(out.end(), parts[p].begin() + o * block, parts[p].begin() + (o + 1) * block);
    }
  return out;
}

void checkConcatColumns(Engine& engine, const std::vector<int64_t>& widths) {
  const int64_t R = 61;
  std::vector<std::vector<float>> parts;
  std::vector<Shape> shapes;
  std::vector<Tensor> tensors;
  int64_t total = 0;
  for (size_t i = 0; i < widths.size(); ++i) {
    parts.push_back(randomUniform(R * widths[i], -1, 1, 91 + uint32_t(i)));
    shapes.push_back({R, widths[i]});
    tensors.push_back(engine.fromFloats(shapes.back(), parts.back()));
    total += widths[i];
  }
  GuardedOutput out(engine, {R, total});
  Recorder rec(engine);
  concatColumns(rec, tensors, out.tensor());
  rec.run();
  EXPECT_EQ(out.read(), concatRef(parts, shapes, 1));
}

TEST_F(EngineTest, ConcatColumns) { checkConcatColumns(eng(), {7, 61, 1, 257}); }
// Widths and offsets that are multiples of 4: the kernel copies vec4s.
TEST_F(EngineTest, ConcatColumnsAligned) { checkConcatColumns(eng(), {8, 64, 4, 256}); }

// Concatenating NCHW maps along channels: each image's block of C_i * H * W values.
TEST_F(EngineTest, ConcatChannelsNCHW) {
  const int64_t N = 2, H = 7, W = 9;
  const Shape sa = {N, 3, H, W}, sb = {N, 61, H, W};
  auto a = randomUniform(shapeNumel(sa), -1, 1, 95), b = randomUniform(shapeNumel(sb), -1, 1, 96);
  GuardedOutput out(eng(), {N, 64, H, W});
  Recorder rec(eng());
  concat(rec, {eng().fromFloats(sa, a), eng().fromFloats(sb, b)}, out.tensor(), 1);
  rec.run();
  EXPECT_EQ(out.read(), concatRef({a, b}, {sa, sb}, 1));
}

TEST_F(EngineTest, SliceColumnsAndChannels) {
  const int64_t R = 257, C = 61;
  auto x = randomUniform(R * C, -1, 1, 97);
  Tensor tx = eng().fromFloats({R, C}, x);
  GuardedOutput cols(eng(), {R, 7});
  const Shape s4 = {2, 61, 7, 9};
  auto m = randomUniform(shapeNumel(s4), -1, 1, 98);
  GuardedOutput chans(eng(), {2, 5, 7, 9});
  Recorder rec(eng());
  sliceColumns(rec, tx, 13, 7, cols.tensor());
  slice(rec, eng().fromFloats(s4, m), 1, 50, 5, chans.tensor());
  rec.run();
  std::vector<float> refCols, refChans;
  for (int64_t r = 0; r < R; ++r) refCols.insert(refCols.end(), x.begin() + r * C + 13, x.begin() + r * C + 20);
  for (int64_t n = 0; n < 2; ++n)
    refChans.insert(refChans.end(), m.begin() + (n * 61 + 50) * 63, m.begin() + (n * 61 + 55) * 63);
  EXPECT_EQ(cols.read(), refCols);
  EXPECT_EQ(chans.read(), refChans);
}

// The raw form: a block of a strided tensor into another, the rest of dst untouched.
TEST_F(EngineTest, Copy2dStridedBlock) {
  const int64_t rows = 61, srcStride = 257, dstStride = 100, cols = 37;
  auto src = randomUniform(rows * srcStride, -1, 1, 99);
  auto dst = randomUniform(rows * dstStride, 5, 6, 100);
  Tensor ts = eng().fromFloats({rows, srcStride}, src), td = eng().fromFloats({rows, dstStride}, dst);
  Recorder rec(eng());
  copy2d(rec, ts, srcStride, 200, td, dstStride, 63, rows, cols);
  rec.run();
  auto ref = dst;
  for (int64_t r = 0; r < rows; ++r)
    for (int64_t c = 0; c < cols; ++c) ref[r * dstStride + 63 + c] = src[r * srcStride + 200 + c];
  EXPECT_EQ(eng().download(td), ref);
}

TEST_F(EngineTest, Copy2dSplitIntoChunks) {
  const int64_t R = 1000, a = 24, b = 16;
  auto xa = randomUniform(R * a, -1, 1, 101), xb = randomUniform(R * b, -1, 1, 102);
  GuardedOutput out(eng(), {R, a + b});
  ScopedBindingRange lowered(eng(), 300 * (a + b) * 4);  // 300 rows of out a chunk
  Recorder rec(eng());
  concatColumns(rec, {eng().fromFloats({R, a}, xa), eng().fromFloats({R, b}, xb)}, out.tensor());
  EXPECT_EQ(rec.pending(), 8u);  // 4 chunks per part
  rec.run();
  lowered.restore();
  EXPECT_EQ(out.read(), concatRef({xa, xb}, {{R, a}, {R, b}}, 1));
}

TEST_F(EngineTest, Copy2dRejectsBadShapes) {
  Tensor a = eng().tensor({4, 6}), b = eng().tensor({4, 5}), out = eng().tensor({4, 10});
  Recorder rec(eng());
  EXPECT_THROW(concatColumns(rec, {a, b}, out), Error);                     // 11 columns for 10
  EXPECT_THROW(concatColumns(rec, {a, eng().tensor({3, 4})}, out), Error);  // rows differ
  EXPECT_THROW(sliceColumns(rec, a, 4, 3, eng().tensor({4, 3})), Error);    // past the end
  EXPECT_THROW(sliceColumns(rec, a, 1, 3, eng().tensor({4, 2})), Error);
  EXPECT_THROW(copy2d(rec, a, 6, 0, a, 6, 0, 4, 6), Error);     // overlap
  EXPECT_THROW(copy2d(rec, a, 6, 2, out, 10, 0, 4, 6), Error);  // columns past the stride
  EXPECT_EQ(rec.pending(), 0u);
}

}  // namespace
}  // namespace spar::test
