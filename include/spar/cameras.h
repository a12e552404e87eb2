// Cameras to render (spar::Session::render): a path through the estimated input cameras, and
// camera files, as `spar render --path N` and `--cameras FILE` use them. Conventions: the
// comment of spar/request.h (OpenCV c2w in the canonical view's frame, normalized intrinsics).
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "spar/export.h"
#include "spar/request.h"

namespace spar {

// `count` cameras along the estimated cameras of `inputs` (positions in the encoded sequence,
// in order): rotations slerped, positions interpolated, every camera with the first input's
// intrinsics (the reference's --path). Throws spar::Error for count < 1 or no inputs.
SPAR_API RenderCameras pathCameras(const Encoded& encoded, const std::vector<int64_t>& inputs, int count);

// The cameras of a nerfstudio transforms.json or a COLMAP text model (a directory holding
// cameras.txt and images.txt, or its images.txt), poses in the canonical view's frame, their
// pixel intrinsics mapped through the image preparation to width x height (the model's size)
// and normalized. A note about the file (e.g. COLMAP distortion ignored) goes to *warning.
// Throws spar::Error (one line naming the file and frame).
SPAR_API RenderCameras readCameras(const std::string& path, int width, int height, std::string* warning = nullptr);

// "" when Session::render takes every camera, else the first one it refuses and why ("camera 3:
// the rotation is not orthonormal ..."): a camera file checked before any device work.
SPAR_API std::string renderCamerasProblem(const RenderCameras& cameras);

}  // namespace spar
