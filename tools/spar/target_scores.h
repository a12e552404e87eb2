// What index.html shows for a request with target frames: each target rendered with its
// estimated camera beside the frame itself, with its PSNR and that of copying the nearest input
// frame (the simplest baseline: a model below it adds nothing the inputs do not already show).
// Whole-image PSNR: moving people count as error for both (a render of the static scene does not
// show them); `spar eval` scores static pixels only.
#pragma once
#include <nlohmann/json.hpp>

#include <cstdint>
#include <string>
#include <vector>

namespace spar::cli {

// Writes target_XX.png (the render) and truth_XX.png (the frame as the model saw it, prepared)
// for each target into `dir` and returns report.json's "targets": per target its position in
// the sequence, the nearest input's, "psnr" and "psnr_copy" (dB). Empty for no targets.
// targetRgb: [T, 3, H, W]; images: [V, 3, H, W].
nlohmann::ordered_json writeTargetScores(const std::string& dir, const std::vector<float>& targetRgb,
                                         const std::vector<float>& images, const std::vector<int64_t>& inputs,
                                         const std::vector<int64_t>& targets, int height, int width);

// The files writeTargetScores writes for `targets` target frames.
int targetFileCount(size_t targets);

}  // namespace spar::cli
