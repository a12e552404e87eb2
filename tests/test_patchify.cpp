// patchify / unpatchify (shaders/patchify.comp via engine/ops/patchify.cpp): exact copies
// against a reference of einops "b c (hh ph) (ww pw) -> b (hh ww) (ph pw c)".
#include "engine/ops/patchify.h"

#include "tests/test_support.h"

namespace spar::test {
namespace {

std::vector<double> patchifyRef(const std::vector<float>& img, int64_t V, int64_t C, int64_t H, int64_t W, int64_t p) {
  const int64_t Hp = H / p, Wp = W / p, F = p * p * C;
  std::vector<double> tok(V * Hp * Wp * F);
  for (int64_t v = 0; v < V; ++v)
    for (int64_t c = 0; c < C; ++c)
      for (int64_t y = 0; y < H; ++y)
        for (int64_t x = 0; x < W; ++x) {
          const int64_t t = (y / p) * Wp + x / p, f = ((y % p) * p + x % p) * C + c;
          tok[(v * Hp * Wp + t) * F + f] = img[((v * C + c) * H + y) * W + x];
        }
  return tok;
}

struct PatchCase {
  int64_t V, C, H, W;
  int p;
};

// Readable test names and failure messages.
std::string describe(const PatchCase& c) {
  return "V" + std::to_string(c.V) + "_C" + std::to_string(c.C) + "_" + std::to_string(c.H) +
         "x" + std::to_string(c.W) + "_p" + std::to_string(c.p);
}
void PrintTo(const PatchCase& c, std::ostream* os) { *os << describe(c); }

class PatchifyTest : public EngineTest, public ::testing::WithParamInterface<PatchCase> {};

TEST_P(PatchifyTest, MatchesReferenceAndRoundTrips) {
  const auto c = GetParam();
  const int64_t T = (c.H / c.p) * (c.W / c.p), F = int64_t(c.p) * c.p * c.C;
  auto img = randomUniform(c.V * c.C * c.H * c.W, -1, 1, 1);
  Tensor timg = eng().fromFloats({c.V, c.C, c.H, c.W}, img);
  GuardedOutput tok(eng(), {c.V, T, F});
  GuardedOutput back(eng(), {c.V, c.C, c.H, c.W});
  Recorder rec(eng());
  patchify(rec, timg, tok.tensor(), c.p);
  unpatchify(rec, tok.tensor(), back.tensor(), c.p);
  rec.run();
  expectClose(tok.read(), patchifyRef(img, c.V, c.C, c.H, c.W, c.p), 0.0, 0.0, "patchify");
  tok.expectAllWritten();
  expectClose(back.read(), toDouble(img), 0.0, 0.0, "round trip");
  back.expectAllWritten();
}

INSTANTIATE_TEST_SUITE_P(Shapes, PatchifyTest,
                         ::testing::Values(PatchCase{2, 3, 28, 42, 14},   // RGB images, ViT patches
                                           PatchCase{1, 61, 14, 6, 2},    // odd channel count
                                           PatchCase{3, 7, 13, 13, 13},   // one patch per image
                                           PatchCase{1, 5, 7, 9, 1},      // p = 1: a transpose
                                           PatchCase{1, 1, 16, 32, 4}),
                         [](const ::testing::TestParamInfo<PatchCase>& info) { return describe(info.param); });

// unpatchify on its own, from tokens the reference laid out.
TEST_F(EngineTest, UnpatchifyMatchesReference) {
  const int64_t V = 2, C = 13, H = 21, W = 14;
  const int p = 7;
  auto img = randomUniform(V * C * H * W, -1, 1, 2);
  auto tokD = patchifyRef(img, V, C, H, W, p);
  std::vector<float> tok(tokD.begin(), tokD.end());
  Tensor ttok = eng().fromFloats({V, (H / p) * (W / p), int64_t(p) * p * C}, tok);
  GuardedOutput out(eng(), {V, C, H, W});
  Recorder rec(eng());
  unpatchify(rec, ttok, out.tensor(), p);
  rec.run();
  expectClose(out.read(), toDouble(img), 0.0, 0.0, "unpatchify");
  out.expectAllWritten();
}

TEST_F(EngineTest, PatchifySplitIntoChunks) {
  const int64_t V = 5, C = 3, H = 8, W = 12;
  const int p = 4;
  auto img = randomUniform(V * C * H * W, -1, 1, 3);
  Tensor timg = eng().fromFloats({V, C, H, W}, img);
  GuardedOutput tok(eng(), {V, 6, 48});
  GuardedOutput back(eng(), {V, C, H, W});
  ScopedBindingRange lowered(eng(), uint64_t(2 * C * H * W + 64) * 4);  // two images a binding
  Recorder rec(eng());
  patchify(rec, timg, tok.tensor(), p);
  const size_t patchifyDispatches = rec.pending();
  unpatchify(rec, tok.tensor(), back.tensor(), p);
  EXPECT_EQ(patchifyDispatches, 3u);
  EXPECT_EQ(rec.pending(), 6u);
  rec.run();
  lowered.restore();
  expectClose(tok.read(), patchifyRef(img, V, C, H, W, p), 0.0, 0.0, "chunked patchify");
  expectClose(back.read(), toDouble(img), 0.0, 0.0, "chunked round trip");
}

TEST_F(EngineTest, PatchifyRejectsBadShapes) {
  Recorder rec(eng());
  Tensor img = eng().tensor({1, 3, 28, 30});
  EXPECT_THROW(patchify(rec, img, eng().tensor({1, 4, 588}), 14), Error);            // W not divisible by p
  Tensor ok = eng().tensor({1, 3, 28, 28});
  EXPECT_THROW(patchify(rec, ok, eng().tensor({1, 4, 587}), 14), Error);             // wrong token size
  EXPECT_THROW(patchify(rec, ok, eng().tensor({1, 2, 2, 588}), 14), Error);          // token rank
  EXPECT_THROW(patchify(rec, ok, eng().tensor({1, 4, 588}), 0), Error);              // p = 0
  EXPECT_THROW(unpatchify(rec, eng().tensor({1, 4, 588}), img, 14), Error);          // W not divisible
  EXPECT_THROW(unpatchify(rec, eng().tensor({2, 4, 588}), ok, 14), Error);           // batch differs
  EXPECT_EQ(rec.pending(), 0u);
}

}  // namespace
}  // namespace spar::test
