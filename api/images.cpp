// spar::loadImage / writePng (include/spar/images.h) on imaging/image_prep.
#include "spar/images.h"

#include "imaging/image_prep.h"
#include "imaging/video_frames.h"
#include "spar/error.h"

namespace spar {

std::vector<float> loadImage(const std::string& path, int height, int width) {
  if (height <= 0 || width <= 0) throw Error("loadImage: size must be positive, got " + std::to_string(height) + "x" + std::to_string(width));
  return loadPreparedImage(path, height, width);
}

std::vector<float> loadVideoFrames(const std::string& path, int height, int width, int count,
                                   const std::vector<double>& at, std::vector<double>* times) {
  if (height <= 0 || width <= 0)
    throw Error("loadVideoFrames: size must be positive, got " + std::to_string(height) + "x" + std::to_string(width));
  const VideoInfo info = probeVideo(path);
  const std::vector<double> when = at.empty() ? spreadTimes(info, count) : at;
  std::vector<float> all;
  for (const RgbImage& frame : readVideoFrames(path, info, when, height, width)) {
    const std::vector<float> img = prepareImage(frame, height, width);
    all.insert(all.end(), img.begin(), img.end());
  }
  if (times) *times = when;
  return all;
}

void writePng(const std::string& path, const std::vector<float>& rgb, int height, int width) {
  if (height <= 0 || width <= 0 || rgb.size() != size_t(3) * size_t(height) * size_t(width))
    throw Error("writePng " + path + ": " + std::to_string(rgb.size()) + " values are not [3, " + std::to_string(height) +
                ", " + std::to_string(width) + "]");
  writePng(path, rgb.data(), 3, height, width);
}

}  // namespace spar
