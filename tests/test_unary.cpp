// Elementwise unary ops (shaders/unary.comp via engine/ops/unary.cpp) against float64 references.
#include "engine/ops/unary.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

double unaryRef(UnaryOp op, double x, double alpha = 1, double beta = 0) {
  switch (op) {
    case UnaryOp::Gelu:
      return 0.5 * x * std::erfc(-x / std::sqrt(2.0));
    case UnaryOp::QuickGelu:
      return x / (1.0 + std::exp(-1.702 * x));
    case UnaryOp::Silu:
      return x / (1.0 + std::exp(-x));
    case UnaryOp::Sigmoid:
      return 1.0 / (1.0 + std::exp(-x));
    case UnaryOp::Relu:
      return std::max(x, 0.0);
    case UnaryOp::Scale:
      return alpha * x + beta;
  }
  return 0;
}

std::vector<double> unaryRef(UnaryOp op, const std::vector<float>& x, double alpha = 1, double beta = 0) {
  std::vector<double> y(x.size());
  for (size_t i = 0; i < x.size(); ++i) y[i] = unaryRef(op, x[i], alpha, beta);
  return y;
}

const char* opName(UnaryOp op) {
  switch (op) {
    case UnaryOp::Gelu:
      return "gelu";
    case UnaryOp::QuickGelu:
      return "quick_gelu";
    case UnaryOp::Silu:
      return "silu";
    case UnaryOp::Sigmoid:
      return "sigmoid";
    case UnaryOp::Relu:
      return "relu";
    case UnaryOp::Scale:
      return "scale";
  }
  return "?";
}

// Every element within rtol of the reference, or below `tiny` in magnitude where the reference is.
void expectRelative(const std::vector<float>& out, const std::vector<double>& ref, double rtol, double tiny,
                    const std::string& what) {
  for (size_t i = 0; i < ref.size(); ++i) {
    ASSERT_TRUE(std::isfinite(out[i])) << what << ": element " << i << " is " << out[i];
    if (std::abs(ref[i]) > tiny) {
      ASSERT_NEAR(out[i] / ref[i], 1.0, rtol) << what << ": element " << i << " got " << out[i] << " want " << ref[i];
    } else {
      ASSERT_LE(std::abs(out[i]), tiny) << what << ": element " << i << " got " << out[i] << " want " << ref[i];
    }
  }
}

// Runs op on x out of place and in place; returns both results.
std::pair<std::vector<float>, std::vector<float>> runBoth(Engine& engine, UnaryOp op, const std::vector<float>& x,
                                                          float alpha = 1, float beta = 0) {
  const int64_t n = static_cast<int64_t>(x.size());
  Tensor tx = engine.fromFloats({n}, x), tin = engine.fromFloats({n}, x);
  GuardedOutput y(engine, {n});
  Recorder rec(engine);
  unary(rec, op, tx, y.tensor(), alpha, beta);
  unary(rec, op, tin, tin, alpha, beta);
  rec.run();
  auto out = y.read();
  y.expectAllWritten();
  return {out, engine.download(tin)};
}

struct UnaryCase {
  UnaryOp op;
  int64_t n;
};
// Readable, stable CTest names (the default prints the struct's bytes, padding included).
void PrintTo(const UnaryCase& c, std::ostream* os) { *os << opName(c.op) << "_n" << c.n; }

class UnaryTest : public EngineTest, public ::testing::WithParamInterface<UnaryCase> {};

TEST_P(UnaryTest, MatchesFloat64Reference) {
  const auto c = GetParam();
  auto x = randomUniform(c.n, -8, 8, 71);
  const float alpha = c.op == UnaryOp::Scale ? 0.37f : 1.0f, beta = c.op == UnaryOp::Scale ? -2.5f : 0.0f;
  auto [out, inPlace] = runBoth(eng(), c.op, x, alpha, beta);
  auto ref = unaryRef(c.op, x, alpha, beta);
  const std::string what = std::string(opName(c.op)) + " n=" + std::to_string(c.n);
  expectClose(out, ref, 1e-10, 1e-5, what);
  expectClose(inPlace, ref, 1e-10, 1e-5, what + " in place");
}

INSTANTIATE_TEST_SUITE_P(OddSizes, UnaryTest,
                         ::testing::Values(UnaryCase{UnaryOp::Gelu, 7}, UnaryCase{UnaryOp::Gelu, 100003},
                                           UnaryCase{UnaryOp::QuickGelu, 61}, UnaryCase{UnaryOp::QuickGelu, 4097},
                                           UnaryCase{UnaryOp::Silu, 257}, UnaryCase{UnaryOp::Silu, 1},
                                           UnaryCase{UnaryOp::Sigmoid, 7}, UnaryCase{UnaryOp::Sigmoid, 65537},
                                           UnaryCase{UnaryOp::Relu, 13}, UnaryCase{UnaryOp::Relu, 4099},
                                           UnaryCase{UnaryOp::Scale, 61}, UnaryCase{UnaryOp::Scale, 1025}));

// Activations at +-1e4 and on the way there: finite, exact where the limit is representable,
// and the negative tails underflow to (nearly) zero instead of producing NaN or Inf.
void checkExtremes(Engine& engine, UnaryOp op) {
  std::vector<float> x;
  for (float v : {1e4f, 9999.5f, 3000.0f, 1000.0f, 100.0f, 88.0f, 40.0f, 20.0f, 9.0f, 3.0f, 1.0f, 1e-3f, 1e-20f})
    x.insert(x.end(), {v, -v});
  x.push_back(0.0f);
  for (int i = 0; i < 40; ++i) x.push_back(i % 2 ? 1e4f : -1e4f);  // past a whole workgroup lane group
  auto [out, inPlace] = runBoth(engine, op, x);
  auto ref = unaryRef(op, x);
  const std::string name = opName(op);
  expectClose(out, ref, 1e-10, 2e-3, name + " at +-1e4");  // 2e-3: an ulp of 1e4 is 9.8e-4
  expectClose(inPlace, ref, 1e-10, 2e-3, name + " at +-1e4 in place");
  expectRelative(out, ref, 1e-5, 1e-30, name);
  const float hi = out[0], lo = out[1];
  if (op == UnaryOp::Sigmoid) {
    EXPECT_EQ(hi, 1.0f);
  } else {
    EXPECT_EQ(hi, 1e4f);
  }
  EXPECT_LE(std::abs(lo), 1e-30f) << name << "(-1e4)";
}

TEST_F(EngineTest, GeluAtPlusMinus1e4) { checkExtremes(eng(), UnaryOp::Gelu); }
TEST_F(EngineTest, QuickGeluAtPlusMinus1e4) { checkExtremes(eng(), UnaryOp::QuickGelu); }
TEST_F(EngineTest, SiluAtPlusMinus1e4) { checkExtremes(eng(), UnaryOp::Silu); }
TEST_F(EngineTest, SigmoidAtPlusMinus1e4) { checkExtremes(eng(), UnaryOp::Sigmoid); }
TEST_F(EngineTest, ReluAtPlusMinus1e4) { checkExtremes(eng(), UnaryOp::Relu); }

// Magnitudes from 1e-3 to 3e38 with both signs: every op finite and relatively accurate.
TEST_F(EngineTest, UnaryLargeMixedValues) {
  const int64_t n = 4099;
  auto e = randomUniform(n, -3.0f, 38.5f, 72), s = randomUniform(n, -1, 1, 73);
  std::vector<float> x(n);
  for (int64_t i = 0; i < n; ++i) x[i] = (s[i] < 0 ? -1.0f : 1.0f) * std::pow(10.0f, e[i]);
  x[0] = 3.4e38f;
  x[1] = -3.4e38f;
  for (UnaryOp op : {UnaryOp::Gelu, UnaryOp::QuickGelu, UnaryOp::Silu, UnaryOp::Sigmoid, UnaryOp::Relu}) {
    auto [out, inPlace] = runBoth(eng(), op, x);
    auto ref = unaryRef(op, x);
    expectClose(out, ref, 1e-10, 1e32, std::string(opName(op)) + " mixed");  // max abs: relative check below
    expectRelative(out, ref, 1e-5, 1e-30, opName(op));
    expectRelative(inPlace, ref, 1e-5, 1e-30, std::string(opName(op)) + " in place");
  }
}

TEST_F(EngineTest, ActivateNoneCopiesAndMatchesOps) {
  const int64_t n = 257;
  auto x = randomUniform(n, -4, 4, 74);
  Tensor tx = eng().fromFloats({n}, x);
  GuardedOutput copy(eng(), {n}), gelu(eng(), {n});
  Recorder rec(eng());
  activate(rec, Activation::None, tx, copy.tensor());
  activate(rec, Activation::None, tx, tx);  // nothing to do
  EXPECT_EQ(rec.pending(), 1u);
  activate(rec, Activation::Gelu, tx, gelu.tensor());
  rec.run();
  EXPECT_EQ(copy.read(), x);
  expectClose(gelu.read(), unaryRef(UnaryOp::Gelu, x), 1e-10, 1e-5, "activate gelu");
}

TEST_F(EngineTest, UnarySplitIntoChunks) {
  const int64_t n = 10003;
  auto x = randomUniform(n, -5, 5, 75);
  Tensor tx = eng().fromFloats({7, 1429, 1}, x);
  GuardedOutput y(eng(), {n});
  ScopedBindingRange lowered(eng(), 4096 * 4);  // 3 chunks
  Recorder rec(eng());
  unary(rec, UnaryOp::Silu, tx, y.tensor());
  EXPECT_EQ(rec.pending(), 3u);
  rec.run();
  lowered.restore();
  expectClose(y.read(), unaryRef(UnaryOp::Silu, x), 1e-10, 1e-5, "chunked");
  y.expectAllWritten();
}

TEST_F(EngineTest, UnaryRejectsBadInput) {
  Tensor x = eng().tensor({4, 8}), y = eng().tensor({4, 7}), xi = eng().tensor({4, 8}, DType::I32);
  Tensor big = eng().tensor({64});
  Recorder rec(eng());
  EXPECT_THROW(unary(rec, UnaryOp::Gelu, x, y), Error);
  EXPECT_THROW(unary(rec, UnaryOp::Gelu, xi, xi), Error);
  EXPECT_THROW(unary(rec, UnaryOp::Gelu, big.view(0, {32}), big.view(4, {32})), Error);  // overlap
  EXPECT_EQ(rec.pending(), 0u);
}

}  // namespace
}  // namespace spar::test
