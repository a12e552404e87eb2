// Error of one mode's output against a reference output (engineering.md "Report error against
// run time": PSNR of RGB, max abs error, mask and label-map agreement).
#pragma once
#include <cstdint>
#include <optional>
#include <vector>

namespace spar::modes {

struct RgbError {
  double psnrDb = 0;  // 10 log10(1 / MSE), RGB in [0, 1]; +inf when identical
  double maxAbs = 0;
};
// Throws spar::Error when the sizes differ.
RgbError rgbError(const std::vector<float>& rgb, const std::vector<float>& reference);

// Share (0..1) of pixels whose binary motion mask (P > threshold) equals the reference's mask
// (0/1 values); nullopt when either side has no motion maps (assume-static).
std::optional<double> maskAgreement(const std::vector<float>& motion, const std::vector<float>& referenceMask,
                                    double threshold);
// Max |P - P_ref| of the motion probabilities; nullopt as above.
std::optional<double> motionMaxAbs(const std::vector<float>& motion, const std::vector<float>& reference);

// Share (0..1) of pixels whose label (prompt index) equals the reference's; nullopt when either
// side has no label maps (no prompts).
std::optional<double> labelAgreement(const std::vector<int32_t>& labels, const std::vector<int32_t>& reference);

}  // namespace spar::modes
