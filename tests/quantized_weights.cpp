#include "tests/quantized_weights.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include <gtest/gtest.h>

#include "tests/test_support.h"

namespace spar::test {

QuantizedMatrix quantizeReference(const std::vector<float>& w, int64_t N, int64_t K, int bits) {
  const int q = bits == 8 ? 127 : 7;
  const size_t codeBytes = size_t(K) * bits / 8, rowBytes = codeBytes + size_t(K) / 32 * 4;
  QuantizedMatrix m{std::vector<uint8_t>(size_t(N) * rowBytes, 0), std::vector<float>(w.size())};
  for (int64_t n = 0; n < N; ++n)
    for (int64_t b = 0; b < K / 32; ++b) {
      const float* blk = w.data() + n * K + b * 32;
      double amax = 0;
      for (int j = 0; j < 32; ++j) amax = std::max(amax, std::abs(double(blk[j])));
      const float scale = float(amax / q);
      std::memcpy(m.rows.data() + size_t(n) * rowBytes + codeBytes + size_t(b) * 4, &scale, 4);
      for (int j = 0; j < 32; ++j) {
        const int64_t k = b * 32 + j;
        const int code = scale > 0 ? int(std::clamp(std::nearbyint(double(blk[j]) / scale), double(-q), double(q))) : 0;
        uint8_t* row = m.rows.data() + size_t(n) * rowBytes;
        if (bits == 8) row[k] = uint8_t(int8_t(code));
        else row[k / 2] |= uint8_t((code + 8) << (4 * (k & 1)));
        m.values[size_t(n * K + k)] = float(code) * scale;
      }
    }
  return m;
}

Tensor quantizedTensor(Engine& engine, const QuantizedMatrix& m, int64_t N, int64_t K, int bits) {
  Tensor t = engine.tensor({N, K}, bits == 8 ? DType::Q8 : DType::Q4);
  EXPECT_EQ(t.bytes(), m.rows.size());
  engine.write(t, m.rows.data(), m.rows.size());
  return t;
}

std::vector<float> stiffQuantizedRows(int64_t N, int64_t K, uint32_t seed) {
  auto w = randomUniform(size_t(N * K), -1e-2f, 1e-2f, seed);
  for (int64_t n = 0; n < N; ++n) {
    w[size_t(n * K + 7)] = n % 2 ? 1e4f : -1e4f;                 // block 0: an outlier
    for (int j = 32; j < 64; ++j) w[size_t(n * K + j)] = 0.0f;  // block 1: zeros
    for (int j = 64; j < 96; ++j)                               // block 2: tiny
      w[size_t(n * K + j)] = float(j % 3 - 1) * 127.0f * std::numeric_limits<float>::min();
  }
  return w;
}

}  // namespace spar::test
