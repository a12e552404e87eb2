// spar/cameras.h: the command line's camera helpers (formats/) behind the public types.
#include "spar/cameras.h"

#include "formats/camera_files.h"
#include "formats/cameras.h"
#include "model/camera_checks.h"

namespace spar {

RenderCameras pathCameras(const Encoded& encoded, const std::vector<int64_t>& inputs, int count) {
  return toRenderCameras(inputCameraPath(encoded, inputs, count));
}

RenderCameras readCameras(const std::string& path, int width, int height, std::string* warning) {
  return toRenderCameras(readCameraFile(path, width, height, warning));
}

std::string renderCamerasProblem(const RenderCameras& cameras) {
  if (cameras.fxfycxcy.size() != cameras.c2w.size()) return "as many intrinsics as poses are needed";
  for (size_t i = 0; i < cameras.size(); ++i)
    if (const std::string p = renderCameraProblem(cameras.c2w[i], cameras.fxfycxcy[i]); !p.empty())
      return "camera " + std::to_string(i) + ": " + p;
  return "";
}

}  // namespace spar
