// Writing a `spar render` run into a directory (the staged temporary one): the file names,
// formats and JSON documents of the reference's Run.write_render / cameras_json / report.
// Views are written as each render chunk arrives (RenderWriter::addViews), so a long --path
// holds one chunk of views on the host, not the whole path.
#pragma once
#include <nlohmann/json.hpp>

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "formats/cameras.h"
#include "imaging/image_prep.h"
#include "tools/spar/animation.h"

namespace spar::cli {

struct RenderLayout {
  int width = 0, height = 0;
  // view_XX files: "png" (8-bit, the reference's rounding), "exr" (float32), "exr16" (half),
  // "npy" (float32 [3, H, W]): the float formats hold the engine's RGB as computed.
  std::string viewFormat = "png";
  // --labels: the prompts; label maps are [H/2, W/2] per view
  std::vector<std::string> labels;
  int64_t featureChannels = 0;  // C of features_XX.npy (--features)
  // > 0: also an animation (path.mp4 or path.gif, as `animation` says) of the views beside
  // their label maps at this many frames a second (a --path render: a smooth camera path)
  int animationFps = 0;
  AnimationChoice animation;
};

// One chunk of rendered views and what was asked for besides them.
struct RenderedViews {
  int64_t count = 0;
  const float* rgb = nullptr;                          // [n, 3, H, W]
  const std::vector<std::vector<int32_t>>* labelMaps = nullptr;  // n maps [H/2 * W/2], or null
  const std::vector<float>* scores = nullptr;          // --scores: [n, P, H/2, W/2], or null
  const std::vector<float>* features = nullptr;        // --features: [n, C, H/2, W/2], or null
};

class RenderWriter {
 public:
  RenderWriter(std::string dir, RenderLayout layout);
  ~RenderWriter();
  RenderWriter(const RenderWriter&) = delete;
  RenderWriter& operator=(const RenderWriter&) = delete;

  // Writes views next .. next + n - 1 (and their label maps, scores, features, animation frames).
  void addViews(const RenderedViews& views);
  // The inputs' motion maps [K, H, W] and binary masks, cameras.json and the COLMAP models;
  // completes the animation. report.json is the caller's, written last so that it can count
  // the time spent here.
  void finish(const std::vector<float>& motion, int64_t motionViews, float maskThreshold, const CamerasDocument& cams);
  // The inputs' SAM2.1-refined masks [K, H, W] (0 or 1) as refined_XX.png, 0 / 255.
  void writeRefined(const std::vector<float>& masks, int64_t views);

  int files() const { return files_; }
  int64_t views() const { return next_; }
  // The animation written ("" if none) and how, e.g. "path.mp4" / "H.264 MP4 through /usr/bin/ffmpeg".
  std::string animationFile() const;
  std::string animationDescription() const;

 private:
  RgbImage frame(const float* rgb, const std::vector<int32_t>* labelMap) const;

  std::string dir_;
  RenderLayout layout_;
  std::unique_ptr<Animation> animation_;
  int64_t next_ = 0;
  int files_ = 0;
};

// Frames side by side on black: every part top-aligned, left to right.
RgbImage besideEachOther(const std::vector<const RgbImage*>& parts);

// A JSON document, written whole (temporary name + rename) with a trailing newline.
void writeJson(const std::string& path, const nlohmann::ordered_json& doc);

}  // namespace spar::cli
