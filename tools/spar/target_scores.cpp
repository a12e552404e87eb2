#include "tools/spar/target_scores.h"

#include <cmath>
#include <cstdio>
#include <filesystem>

#include "imaging/image_prep.h"
#include "spar/error.h"
#include "tools/spar/eval_metrics.h"

namespace spar::cli {

nlohmann::ordered_json writeTargetScores(const std::string& dir, const std::vector<float>& targetRgb,
                                         const std::vector<float>& images, const std::vector<int64_t>& inputs,
                                         const std::vector<int64_t>& targets, int height, int width) {
  nlohmann::ordered_json out = nlohmann::ordered_json::array();
  if (targets.empty()) return out;
  const size_t plane = size_t(height) * size_t(width), view = 3 * plane;
  if (targetRgb.size() != targets.size() * view) throw Error("target renders: expected " + std::to_string(targets.size()) + " views");
  const std::vector<uint8_t> allStatic(plane, 0);  // whole-image PSNR
  // A PSNR of identical images is +inf, which JSON cannot hold: null then.
  auto db = [](double v) { return std::isfinite(v) ? nlohmann::ordered_json(v) : nlohmann::ordered_json(); };
  for (size_t j = 0; j < targets.size(); ++j) {
    const float* render = targetRgb.data() + j * view;
    const float* truth = images.data() + size_t(targets[j]) * view;
    const int64_t nearest = eval::nearestInput(targets[j], inputs);
    const float* copy = images.data() + size_t(nearest) * view;
    char name[32];
    std::snprintf(name, sizeof name, "target_%02zu.png", j);
    writePng((std::filesystem::path(dir) / name).string(), render, 3, height, width);
    std::snprintf(name, sizeof name, "truth_%02zu.png", j);
    writePng((std::filesystem::path(dir) / name).string(), truth, 3, height, width);
    out.push_back({{"view", targets[j]},
                   {"nearest_input", nearest},
                   {"psnr", db(*eval::staticPsnr(render, truth, allStatic.data(), height, width))},
                   {"psnr_copy", db(*eval::staticPsnr(copy, truth, allStatic.data(), height, width))}});
  }
  return out;
}

int targetFileCount(size_t targets) { return int(2 * targets); }

}  // namespace spar::cli
