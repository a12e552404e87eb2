// The official label map in float64 (label_reference.h).
#include "tests/label_reference.h"

#include <algorithm>
#include <cmath>

namespace spar::test {

std::vector<double> upsampledLogits(const std::vector<double>& logits, int64_t R, int64_t P, int64_t h, int64_t w) {
  const int64_t H = 2 * h, W = 2 * w;
  std::vector<double> out(size_t(R * P * H * W));
  // align_corners: src = dst (in - 1) / (out - 1); neighbours floor(src) and the next, clamped
  auto coord = [](int64_t dst, int64_t in, int64_t outSize, int64_t& i0, int64_t& i1, double& l) {
    const double src = outSize > 1 ? double(dst) * double(in - 1) / double(outSize - 1) : 0.0;
    i0 = std::min<int64_t>(int64_t(std::floor(src)), in - 1);
    i1 = std::min<int64_t>(i0 + 1, in - 1);
    l = src - double(i0);
  };
  for (int64_t rp = 0; rp < R * P; ++rp)
    for (int64_t y = 0; y < H; ++y) {
      int64_t y0, y1;
      double ly;
      coord(y, h, H, y0, y1, ly);
      for (int64_t x = 0; x < W; ++x) {
        int64_t x0, x1;
        double lx;
        coord(x, w, W, x0, x1, lx);
        const double* p = &logits[size_t(rp * h * w)];
        out[size_t((rp * H + y) * W + x)] = (1 - ly) * ((1 - lx) * p[y0 * w + x0] + lx * p[y0 * w + x1]) +
                                            ly * ((1 - lx) * p[y1 * w + x0] + lx * p[y1 * w + x1]);
      }
    }
  return out;
}

std::vector<int64_t> firstArgmax(const std::vector<double>& scores, int64_t R, int64_t P, int64_t n) {
  std::vector<int64_t> maps;
  maps.reserve(size_t(R * n));
  for (int64_t r = 0; r < R; ++r)
    for (int64_t i = 0; i < n; ++i) {
      int64_t best = 0;
      for (int64_t p = 1; p < P; ++p)
        if (scores[size_t((r * P + p) * n + i)] > scores[size_t((r * P + best) * n + i)]) best = p;
      maps.push_back(best);
    }
  return maps;
}

}  // namespace spar::test
