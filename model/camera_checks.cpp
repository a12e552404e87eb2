#include "model/camera_checks.h"

#include <cmath>
#include <cstdio>

namespace spar {

std::string renderCameraProblem(const std::array<float, 16>& m, const std::array<float, 4>& k) {
  for (float x : m)
    if (!std::isfinite(x)) return "camera-to-world matrix holds a NaN or infinity";
  for (float x : k)
    if (!std::isfinite(x)) return "intrinsics hold a NaN or infinity";
  if (m[12] != 0 || m[13] != 0 || m[14] != 0 || m[15] != 1) return "camera-to-world bottom row is not 0 0 0 1";
  double worst = 0;
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) {
      double dot = 0;
      for (int r = 0; r < 3; ++r) dot += double(m[r * 4 + a]) * double(m[r * 4 + b]);
      worst = std::max(worst, std::abs(dot - (a == b ? 1.0 : 0.0)));
    }
  const auto R = [&](int r, int c) { return double(m[r * 4 + c]); };
  const double det = R(0, 0) * (R(1, 1) * R(2, 2) - R(1, 2) * R(2, 1)) - R(0, 1) * (R(1, 0) * R(2, 2) - R(1, 2) * R(2, 0)) +
                     R(0, 2) * (R(1, 0) * R(2, 1) - R(1, 1) * R(2, 0));
  char buf[160];
  if (worst > kRotationTolerance || std::abs(det - 1) > kRotationTolerance) {
    std::snprintf(buf, sizeof(buf), "rotation is not orthonormal with determinant 1 (max |R^T R - I| %.3g, det %.3g; tolerance %g)",
                  worst, det, kRotationTolerance);
    return buf;
  }
  const double t = std::sqrt(R(0, 3) * R(0, 3) + R(1, 3) * R(1, 3) + R(2, 3) * R(2, 3));
  if (t > kMaxTranslation) {
    std::snprintf(buf, sizeof(buf), "position %.3g from the canonical camera, more than %g (scenes are a few units)", t,
                  kMaxTranslation);
    return buf;
  }
  if (!(k[0] > 0 && k[1] > 0 && k[0] <= kMaxFocal && k[1] <= kMaxFocal)) {
    std::snprintf(buf, sizeof(buf), "normalized focal lengths fx/W %.3g, fy/H %.3g are not in (0, %g]", k[0], k[1], kMaxFocal);
    return buf;
  }
  if (std::abs(k[2]) > kMaxCentre || std::abs(k[3]) > kMaxCentre) {
    std::snprintf(buf, sizeof(buf), "normalized principal point %.3g, %.3g is beyond +-%g", k[2], k[3], kMaxCentre);
    return buf;
  }
  return "";
}

}  // namespace spar
