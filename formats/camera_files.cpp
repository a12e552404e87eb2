#include "formats/camera_files.h"

#include "formats/colmap.h"

namespace spar {

std::vector<CameraD> readCameraFile(const std::string& path, int width, int height, std::string* warning) {
  if (isColmapPath(path)) {
    ColmapCameras m = readColmap(path, width, height);
    if (warning) *warning = m.warning;
    return std::move(m.cameras);
  }
  if (warning) warning->clear();
  return readTransforms(path, width, height);
}

}  // namespace spar
