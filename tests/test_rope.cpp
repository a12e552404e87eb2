// RoPE (shaders/rope.comp via engine/ops/rope.cpp) against a float64 CPU reference. The tables
// are random fp32 values whose two halves differ, so a kernel that assumed DINOv3's tiled tables
// (or swapped sin and cos, or the halves) would fail; the reference reads the same fp32 values.
#include <cstring>

#include "engine/ops/rope.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

struct RopeCase {
  std::string name;
  int64_t B, N, heads, dh, prefix;
  int64_t extraCols = 0;  // columns past 3D (C = 3D + extraCols)
};
void PrintTo(const RopeCase& c, std::ostream* os) { *os << c.name; }

// qkv [B, N, C] rotated as rope() documents, in float64.
std::vector<double> ropeRef(const std::vector<float>& qkv, const RopeCase& c, int64_t C, const std::vector<float>& sin,
                            const std::vector<float>& cos) {
  std::vector<double> y = toDouble(qkv);
  const int64_t half = c.dh / 2;
  for (int64_t b = 0; b < c.B; ++b)
    for (int64_t n = c.prefix; n < c.N; ++n)
      for (int64_t h = 0; h < 2 * c.heads; ++h) {  // q heads, then k heads
        const int64_t e = (b * c.N + n) * C + h * c.dh, t = (n - c.prefix) * c.dh;
        for (int64_t j = 0; j < half; ++j) {
          const double a = qkv[e + j], bb = qkv[e + half + j];
          y[e + j] = a * double(cos[t + j]) - bb * double(sin[t + j]);
          y[e + half + j] = bb * double(cos[t + half + j]) + a * double(sin[t + half + j]);
        }
      }
  return y;
}

class RopeTest : public EngineTest, public ::testing::WithParamInterface<RopeCase> {};

// Measured on lavapipe: NMSE <= 8.3e-16 and max abs <= 8.3e-7 in every case (two products and a
// sum in fp32). Threshold 1e-12 (elementwise budget 1e-10, tightened to what a 2-term
// expression can be expected to give) and max abs 2e-6 for values of a few units.
TEST_P(RopeTest, MatchesFloat64Reference) {
  const RopeCase c = GetParam();
  const int64_t D = c.heads * c.dh, C = 3 * D + c.extraCols, rotated = c.N - c.prefix;
  const std::vector<float> x = randomNormal(c.B * c.N * C, 0.0f, 2.0f, 11);
  const std::vector<float> sin = randomUniform(rotated * c.dh, -1.0f, 1.0f, 12);
  const std::vector<float> cos = randomUniform(rotated * c.dh, -1.0f, 1.0f, 13);
  GuardedOutput qkv(eng(), {c.B, c.N, C});
  eng().upload(qkv.tensor(), x);
  const Tensor tsin = eng().fromFloats({rotated, c.dh}, sin), tcos = eng().fromFloats({rotated, c.dh}, cos);
  Recorder rec(eng());
  rope(rec, qkv.tensor(), c.heads, c.dh, c.prefix, tsin, tcos);
  rec.run();
  const std::vector<float> y = qkv.read();  // also checks the guard words
  expectClose(y, ropeRef(x, c, C, sin, cos), 1e-12, 2e-6, c.name);

  // Prefix tokens, v and the columns past 2D are untouched, bit for bit.
  size_t changed = 0;
  for (int64_t b = 0; b < c.B; ++b)
    for (int64_t n = 0; n < c.N; ++n)
      for (int64_t col = 0; col < C; ++col) {
        if (n >= c.prefix && col < 2 * D) continue;
        const int64_t e = (b * c.N + n) * C + col;
        changed += std::memcmp(&x[e], &y[e], sizeof(float)) != 0;
      }
  EXPECT_EQ(changed, 0u) << "values outside q and k of the rotated tokens changed";
}

INSTANTIATE_TEST_SUITE_P(
    Shapes, RopeTest,
    ::testing::Values(RopeCase{"vec4_prefix0", 2, 61, 3, 8, 0},           // dh/2 = 4: vec4 units
                      RopeCase{"vec4_prefix5", 2, 61, 3, 8, 5},
                      RopeCase{"scalar_prefix5", 3, 37, 2, 12, 5},        // dh/2 = 6: one pair per invocation
                      RopeCase{"scalar_odd_cols", 2, 7, 3, 6, 0, 3},      // C = 3D + 3: rows not on vec4s
                      RopeCase{"dino_like", 2, 261, 12, 64, 5},           // DINOv3 ViT-B/16 at 256x256
                      RopeCase{"all_prefix", 2, 5, 2, 8, 5}),             // nothing to rotate
    [](const auto& info) { return info.param.name; });

TEST_F(EngineTest, RopeRejectsBadShapes) {
  const Tensor qkv = eng().tensor({1, 9, 3 * 16});
  const Tensor t4 = eng().tensor({4, 8}), t5 = eng().tensor({5, 8});
  Recorder rec(eng());
  EXPECT_THROW(rope(rec, qkv, 2, 8, 5, t5, t5), Error);   // tables for 5 tokens, 4 rotated
  EXPECT_THROW(rope(rec, qkv, 4, 8, 5, t4, t4), Error);   // q and k of 4 heads exceed C
  EXPECT_THROW(rope(rec, qkv, 2, 8, 10, t4, t4), Error);  // prefix past N
  EXPECT_THROW(rope(rec, qkv, 2, 7, 5, t4, t4), Error);   // odd head dim
  EXPECT_NO_THROW(rope(rec, qkv, 2, 8, 5, t4, t4));
  rec.run();
}

}  // namespace
}  // namespace spar::test
