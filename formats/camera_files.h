// Camera files of any kind the tools read: a COLMAP text model (a directory or its images.txt,
// formats/colmap.h) or else a nerfstudio transforms.json (formats/cameras.h). One entry point
// for `spar render --cameras`, the public spar::readCameras and the Python module.
#pragma once
#include <string>
#include <vector>

#include "formats/cameras.h"

namespace spar {

// The file's cameras for the model's width x height (intrinsics through the image preparation,
// normalized). A COLMAP model's note (e.g. an ignored distortion) goes to *warning when given.
// Throws spar::Error with one line naming the file.
std::vector<CameraD> readCameraFile(const std::string& path, int width, int height, std::string* warning = nullptr);

}  // namespace spar
