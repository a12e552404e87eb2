// NaN / infinity counting (shaders/count_nonfinite.comp via engine/ops/count_nonfinite.cpp):
// exact counts on odd sizes, several slots accumulating, extreme finite values (3e38,
// subnormals, -0) never counted.
#include <cmath>
#include <limits>

#include "engine/ops/count_nonfinite.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

std::vector<int32_t> readCounts(const Tensor& counts) {
  std::vector<int32_t> out(size_t(counts.numel()));
  engine().read(counts, out.data(), out.size() * 4);
  return out;
}

TEST_F(EngineTest, CountNonFiniteIsExact) {
  const float nan = std::numeric_limits<float>::quiet_NaN(), inf = std::numeric_limits<float>::infinity();
  for (int64_t n : {1, 3, 4, 5, 1023, 1025, 4097, 100003}) {
    std::vector<float> x = randomUniform(n, -1, 1, uint32_t(n));
    int32_t expected = 0;
    for (int64_t i = 0; i < n; i += 7) {
      const int kind = int(i / 7) % 5;
      x[size_t(i)] = kind == 0 ? nan : kind == 1 ? inf : kind == 2 ? -inf : kind == 3 ? 3e38f : 1e-42f;
      expected += kind < 3;
    }
    if ((n - 1) % 7) x[size_t(n - 1)] = -0.0f;
    const Tensor t = eng().fromFloats({n}, x);
    const Tensor counts = eng().tensor({3}, DType::I32);
    const std::vector<int32_t> zeros(3, 0);
    eng().write(counts, zeros.data(), 12);
    Recorder rec(eng());
    countNonFinite(rec, t, counts, 1);
    countNonFinite(rec, t, counts, 1);  // accumulates
    countNonFinite(rec, eng().fromFloats({2}, std::vector<float>{0.0f, 1.0f}), counts, 2);
    rec.run();
    EXPECT_EQ(readCounts(counts), (std::vector<int32_t>{0, 2 * expected, 0})) << "n=" << n;
  }
}

TEST_F(EngineTest, CountNonFiniteRejectsBadArguments) {
  const Tensor x = eng().tensor({8}), counts = eng().tensor({2}, DType::I32);
  Recorder rec(eng());
  EXPECT_THROW(countNonFinite(rec, x, counts, 2), Error);
  EXPECT_THROW(countNonFinite(rec, x, counts, -1), Error);
  EXPECT_THROW(countNonFinite(rec, x, eng().tensor({2}), 0), Error);
  EXPECT_THROW(countNonFinite(rec, eng().tensor({8}, DType::I32), counts, 0), Error);
  EXPECT_EQ(rec.pending(), 0u);
}

}  // namespace
}  // namespace spar::test
