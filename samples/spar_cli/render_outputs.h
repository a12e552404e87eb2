// Writing a finished `spar render` run into a directory (the staged temporary one): the file
// names, formats and JSON documents of the reference's Run.write_render / cameras_json / report.
#pragma once
#include <nlohmann/json.hpp>

#include <cstdint>
#include <string>
#include <vector>

#include "formats/cameras.h"
#include "imaging/image_prep.h"

namespace spar::cli {

struct RenderResult {
  int width = 0, height = 0;
  std::vector<float> rgb;      // [R, 3, H, W] rendered views
  // view_XX files: "png" (8-bit, the reference's rounding), "exr" (float32), "exr16" (half),
  // "npy" (float32 [3, H, W]): the float formats hold the engine's RGB as computed.
  std::string viewFormat = "png";
  int64_t rendered = 0;
  std::vector<float> motion;   // [K, H, W] P(dynamic) of the inputs (empty: --assume-static)
  int64_t motionViews = 0;
  float maskThreshold = 0.5f;
  CamerasDocument cameras;     // cameras.json
  // --labels: the prompts and one label map [h, w] per rendered view (h = H/2)
  std::vector<std::string> labels;
  std::vector<std::vector<int32_t>> labelMaps;
  int labelHeight = 0, labelWidth = 0;
  std::vector<float> scores;  // --scores: [R, P, h, w] per-label score maps
  // --features: [R, C, h, w] semantic features
  std::vector<float> features;
  int64_t featureChannels = 0;
  // > 0: also path.gif, the rendered views (beside their label maps) at this many frames a
  // second (a --path render: the views are a smooth camera path)
  int animationFps = 0;
};

// Writes the images and cameras.json into `dir` (report.json is the caller's, written last
// so that it can count the time spent here); returns the number of files written.
int writeRenderOutputs(const std::string& dir, const RenderResult& result);

// The frames of path.gif: each rendered view, beside its label map (with legend) if any.
std::vector<RgbImage> animationFrames(const RenderResult& result);

// A JSON document, written whole (temporary name + rename) with a trailing newline.
void writeJson(const std::string& path, const nlohmann::ordered_json& doc);

}  // namespace spar::cli
