#include "tools/spar_modes/accuracy.h"

#include <cmath>
#include <limits>
#include <string>

#include "spar/error.h"

namespace spar::modes {
namespace {

void sameSize(size_t a, size_t b, const char* what) {
  if (a != b) throw Error(std::string(what) + ": the engine gave " + std::to_string(a) + " values, the reference " +
                          std::to_string(b));
}

}  // namespace

RgbError rgbError(const std::vector<float>& rgb, const std::vector<float>& reference) {
  sameSize(rgb.size(), reference.size(), "rendered RGB");
  double sum = 0, maxAbs = 0;
  for (size_t i = 0; i < rgb.size(); ++i) {
    const double d = double(rgb[i]) - double(reference[i]);
    sum += d * d;
    maxAbs = std::max(maxAbs, std::abs(d));
  }
  const double mse = rgb.empty() ? 0 : sum / double(rgb.size());
  return {mse > 0 ? -10.0 * std::log10(mse) : std::numeric_limits<double>::infinity(), maxAbs};
}

std::optional<double> maskAgreement(const std::vector<float>& motion, const std::vector<float>& referenceMask,
                                    double threshold) {
  if (motion.empty() || referenceMask.empty()) return std::nullopt;
  sameSize(motion.size(), referenceMask.size(), "motion masks");
  size_t same = 0;
  for (size_t i = 0; i < motion.size(); ++i) same += (motion[i] > threshold) == (referenceMask[i] != 0.0f);
  return double(same) / double(motion.size());
}

std::optional<double> motionMaxAbs(const std::vector<float>& motion, const std::vector<float>& reference) {
  if (motion.empty() || reference.empty()) return std::nullopt;
  sameSize(motion.size(), reference.size(), "motion maps");
  double m = 0;
  for (size_t i = 0; i < motion.size(); ++i) m = std::max(m, std::abs(double(motion[i]) - double(reference[i])));
  return m;
}

std::optional<double> labelAgreement(const std::vector<int32_t>& labels, const std::vector<int32_t>& reference) {
  if (labels.empty() || reference.empty()) return std::nullopt;
  sameSize(labels.size(), reference.size(), "label maps");
  size_t same = 0;
  for (size_t i = 0; i < labels.size(); ++i) same += labels[i] == reference[i];
  return double(same) / double(labels.size());
}

}  // namespace spar::modes
