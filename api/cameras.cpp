// spar/cameras.h: the command line's camera helpers (formats/) behind the public types.
#include "spar/cameras.h"

#include "formats/camera_files.h"
#include "formats/cameras.h"

namespace spar {

RenderCameras pathCameras(const Encoded& encoded, const std::vector<int64_t>& inputs, int count) {
  return toRenderCameras(inputCameraPath(encoded, inputs, count));
}

RenderCameras readCameras(const std::string& path, int width, int height, std::string* warning) {
  return toRenderCameras(readCameraFile(path, width, height, warning));
}

}  // namespace spar
