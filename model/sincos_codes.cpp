#include "model/sincos_codes.h"

#include <cmath>

namespace spar {

std::vector<double> sincos1d(int64_t dim, const std::vector<double>& positions) {
  const int64_t half = dim / 2;
  std::vector<double> out(positions.size() * dim);
  for (size_t i = 0; i < positions.size(); ++i)
    for (int64_t k = 0; k < half; ++k) {
      const double freq = 1.0 / std::pow(10000.0, double(k) / double(half));
      const double a = positions[i] * freq;
      out[i * dim + k] = std::sin(a);
      out[i * dim + half + k] = std::cos(a);
    }
  return out;
}

std::vector<double> sincos2d(int64_t dim, int64_t gh, int64_t gw) {
  const int64_t n = gh * gw, half = dim / 2;
  std::vector<double> a(n), b(n);
  for (int64_t k = 0; k < n; ++k) {
    a[k] = double(k / gh);
    b[k] = double(k % gh);
  }
  const std::vector<double> ca = sincos1d(half, a), cb = sincos1d(half, b);
  std::vector<double> out(n * dim);
  for (int64_t k = 0; k < n; ++k)
    for (int64_t j = 0; j < half; ++j) {
      out[k * dim + j] = ca[k * half + j];
      out[k * dim + half + j] = cb[k * half + j];
    }
  return out;
}

namespace {
std::vector<double> viewIndices(int64_t views) {
  std::vector<double> v(views);
  for (int64_t i = 0; i < views; ++i) v[i] = double(i);
  return v;
}
std::vector<float> toFloat(const std::vector<double>& v) { return {v.begin(), v.end()}; }
}  // namespace

std::vector<float> imageTokenCode(int64_t d, int64_t gh, int64_t gw, int64_t views) {
  const int64_t n = gh * gw, half = d / 2;
  const std::vector<double> spatial = sincos2d(half, gh, gw), temporal = sincos1d(half, viewIndices(views));
  std::vector<float> out(views * n * d);
  for (int64_t v = 0; v < views; ++v)
    for (int64_t k = 0; k < n; ++k) {
      float* row = out.data() + (v * n + k) * d;
      for (int64_t j = 0; j < half; ++j) {
        row[j] = float(spatial[k * half + j]);
        row[half + j] = float(temporal[v * half + j]);
      }
    }
  return out;
}

std::vector<float> cameraTokenCode(int64_t d, int64_t views) { return toFloat(sincos1d(d, viewIndices(views))); }

std::vector<float> gatingCode(int64_t d, int64_t gh, int64_t gw) { return toFloat(sincos2d(d, gh, gw)); }

}  // namespace spar
