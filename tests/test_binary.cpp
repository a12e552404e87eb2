// Elementwise add / multiply with broadcasting (shaders/binary.comp via engine/ops/binary.cpp)
// against float64 references.
#include "engine/ops/binary.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

// out[i] = a[i] op b[(i / bInner) % b.size()]
std::vector<double> binaryRef(BinaryOp op, const std::vector<float>& a, const std::vector<float>& b, int64_t bInner) {
  std::vector<double> y(a.size());
  for (size_t i = 0; i < a.size(); ++i) {
    const double bv = b[(int64_t(i) / bInner) % int64_t(b.size())];
    y[i] = op == BinaryOp::Add ? a[i] + bv : a[i] * bv;
  }
  return y;
}

struct BroadcastCase {
  Shape a, b;
  int64_t bInner;  // what NumPy broadcasting means for the reference
};
// Readable, stable CTest names.
void PrintTo(const BroadcastCase& c, std::ostream* os) {
  for (size_t i = 0; i < c.a.size(); ++i) *os << (i ? "x" : "") << c.a[i];
  *os << "_with_";
  for (size_t i = 0; i < c.b.size(); ++i) *os << (i ? "x" : "") << c.b[i];
}

std::string caseName(const BroadcastCase& c) { return shapeString(c.a) + " with " + shapeString(c.b); }

class BroadcastTest : public EngineTest, public ::testing::WithParamInterface<BroadcastCase> {};

TEST_P(BroadcastTest, AddAndMulMatchFloat64Reference) {
  const auto c = GetParam();
  auto a = randomUniform(shapeNumel(c.a), -4, 4, 81), b = randomUniform(shapeNumel(c.b), -4, 4, 82);
  Tensor ta = eng().fromFloats(c.a, a), tb = eng().fromFloats(c.b, b);
  GuardedOutput sum(eng(), c.a), prod(eng(), c.a);
  Recorder rec(eng());
  add(rec, ta, tb, sum.tensor());
  mul(rec, ta, tb, prod.tensor());
  rec.run();
  expectClose(sum.read(), binaryRef(BinaryOp::Add, a, b, c.bInner), 1e-10, 1e-6, "add " + caseName(c));
  expectClose(prod.read(), binaryRef(BinaryOp::Mul, a, b, c.bInner), 1e-10, 1e-5, "mul " + caseName(c));
  sum.expectAllWritten();
  prod.expectAllWritten();
}

INSTANTIATE_TEST_SUITE_P(Shapes, BroadcastTest,
                         ::testing::Values(BroadcastCase{{7}, {7}, 1},  // same shape
                                           BroadcastCase{{61, 257}, {61, 257}, 1},
                                           BroadcastCase{{61, 257}, {257}, 1},            // bias per column
                                           BroadcastCase{{61, 64}, {64}, 1},              // ... read as vec4
                                           BroadcastCase{{2, 61, 8, 8}, {61, 1, 1}, 64},  // one b value per vec4
                                           BroadcastCase{{2, 61, 7}, {1, 7}, 1},
                                           BroadcastCase{{2, 61, 7, 9}, {61, 1, 1}, 63},  // per channel of NCHW
                                           BroadcastCase{{2, 61, 7, 9}, {1, 61, 1, 1}, 63},
                                           BroadcastCase{{257, 7}, {257, 1}, 7},         // per row
                                           BroadcastCase{{3, 5, 7, 11}, {5, 7, 1}, 11},  // a block of b
                                           BroadcastCase{{61, 7}, {1}, 427},             // one value
                                           BroadcastCase{{1}, {1}, 1}));

TEST_F(EngineTest, BinaryInPlace) {
  const int64_t R = 257, C = 61;
  auto a = randomUniform(R * C, -4, 4, 83), bias = randomUniform(C, -1, 1, 84), other = randomUniform(R * C, -4, 4, 85);
  Tensor ta = eng().fromFloats({R, C}, a), tb = eng().fromFloats({C}, bias), to = eng().fromFloats({R, C}, other);
  Recorder rec(eng());
  add(rec, ta, tb, ta);  // out is a
  mul(rec, ta, to, to);  // out is b (same shape): commutes
  rec.run();
  auto afterAdd = binaryRef(BinaryOp::Add, a, bias, 1);
  std::vector<double> expected(afterAdd.size());
  for (size_t i = 0; i < expected.size(); ++i) expected[i] = double(float(afterAdd[i])) * other[i];
  expectClose(eng().download(ta), afterAdd, 1e-10, 1e-6, "add in place");
  expectClose(eng().download(to), expected, 1e-10, 1e-5, "mul into b");
}

// b a row in the middle of a table (an embedding's second row): its start, 128 bytes in, is no
// multiple of a device's 256-byte storage alignment (device_profile.vulkan-1.2-min.test_binary).
TEST_F(EngineTest, BinaryBroadcastOfARowAtAnyOffset) {
  const int64_t R = 9, C = 32;
  auto a = randomUniform(R * C, -4, 4, 86), table = randomUniform(2 * C, -1, 1, 87);
  const Tensor ta = eng().fromFloats({R, C}, a), tt = eng().fromFloats({2, C}, table);
  const Tensor row = tt.view(C, {C});
  Recorder rec(eng());
  add(rec, ta, row, ta);
  rec.run();
  const std::vector<float> second(table.begin() + C, table.end());
  expectClose(eng().download(ta), binaryRef(BinaryOp::Add, a, second, 1), 1e-10, 1e-6, "add of a row at 128 bytes");
}

// a split into chunks: b's index continues across chunk boundaries (bPhase).
TEST_F(EngineTest, BinarySplitIntoChunks) {
  const int64_t N = 3, C = 7, HW = 1000;
  auto a = randomUniform(N * C * HW, -4, 4, 86), b = randomUniform(C, -1, 1, 87);
  Tensor ta = eng().fromFloats({N, C, HW}, a), tb = eng().fromFloats({C, 1}, b);
  GuardedOutput out(eng(), {N, C, HW});
  ScopedBindingRange lowered(eng(), 4100 * 4);  // chunks of 4100: not a multiple of HW or C*HW
  Recorder rec(eng());
  add(rec, ta, tb, out.tensor());
  EXPECT_EQ(rec.pending(), 6u);
  rec.run();
  lowered.restore();
  expectClose(out.read(), binaryRef(BinaryOp::Add, a, b, HW), 1e-10, 1e-6, "chunked");
  out.expectAllWritten();
}

TEST_F(EngineTest, BinaryExplicitRepeat) {
  const int64_t n = 1001, bInner = 13;
  auto a = randomUniform(n, -4, 4, 88), b = randomUniform(5, -1, 1, 89);
  Tensor ta = eng().fromFloats({n}, a), tb = eng().fromFloats({5}, b);
  GuardedOutput out(eng(), {n});
  Recorder rec(eng());
  binary(rec, BinaryOp::Mul, ta, tb, out.tensor(), bInner);
  rec.run();
  expectClose(out.read(), binaryRef(BinaryOp::Mul, a, b, bInner), 1e-10, 1e-5, "explicit");
}

TEST_F(EngineTest, BinaryRejectsBadShapes) {
  Tensor a = eng().tensor({4, 6, 5}), out = eng().tensor({4, 6, 5});
  Recorder rec(eng());
  EXPECT_THROW(add(rec, a, eng().tensor({4}), out), Error);           // trailing dims do not match
  EXPECT_THROW(add(rec, a, eng().tensor({4, 1, 5}), out), Error);     // repeats inside b
  EXPECT_THROW(add(rec, a, eng().tensor({2, 4, 6, 5}), out), Error);  // b larger than a
  EXPECT_THROW(add(rec, a, eng().tensor({5}), eng().tensor({4, 6})), Error);
  EXPECT_THROW(mul(rec, a, eng().tensor({5}, DType::I32), out), Error);
  EXPECT_EQ(rec.pending(), 0u);
}

}  // namespace
}  // namespace spar::test
