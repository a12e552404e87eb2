// COLMAP text models (https://colmap.github.io/format.html), in and out, so that the cameras of
// a reconstruction can be rendered and SPAR's cameras used by other tools.
//
// cameras.txt: one line per camera `CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`, pixel intrinsics of
// a WIDTH x HEIGHT image (principal point measured from the image corner, as cameras.json's).
// images.txt: two lines per image, `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`, then the 2D
// points line (may be empty, not read); (QW, QX, QY, QZ) and T are world-to-camera
// (x_cam = R(q) x_world + T) in OpenCV axes, the same axes as SPAR's c2w. Lines starting with
// '#' are comments, as are blank lines where an image line is expected (as COLMAP reads them).
//
// Reading (what `spar render --cameras DIR` does):
//  - camera models SIMPLE_PINHOLE (f cx cy), PINHOLE (fx fy cx cy), and SIMPLE_RADIAL,
//    RADIAL, OPENCV, FULL_OPENCV whose distortion is dropped: SPAR renders pinhole cameras,
//    so non-zero distortion costs one warning line (ColmapCameras::warning), not an error,
//    because the pinhole part is what those views look like near the centre. Fisheye models
//    are refused: dropping their distortion would render a different camera.
//  - views in ascending IMAGE_ID: COLMAP writes images.txt in that order and SPAR writes the
//    ids 1..N in its view order, so a written model reads back in the order it was written
//    (file names need not sort the way the sequence goes).
//  - intrinsics follow the image preparation to the model size (normalizedIntrinsics), as
//    readTransforms does.
//  - errors are spar::Error, one line naming the file and line: "P/images.txt:7: expected 10
//    fields (IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME), got 8".
// The poses are used as they are: they must be in SPAR's frame (world = the canonical view's
// camera, SPAR's scale), as those of a model `spar render` wrote.
#pragma once
#include <string>
#include <vector>

#include "formats/cameras.h"

namespace spar {

struct ColmapCameras {
  std::vector<CameraD> cameras;    // c2w OpenCV, normalized intrinsics, by IMAGE_ID
  std::vector<std::string> names;  // NAME of each image
  std::string warning;             // "" or one line: whose distortion was dropped
};

// True for what readColmap takes: a directory, or a file named images.txt.
bool isColmapPath(const std::string& path);

// A directory holding cameras.txt and images.txt, or the path of images.txt with cameras.txt
// beside it; intrinsics normalized to outWidth x outHeight.
ColmapCameras readColmap(const std::string& path, int outWidth, int outHeight);

// Writes `dir` (created if missing) as a COLMAP text model: cameras.txt with one PINHOLE camera
// per view at width x height pixels (CAMERA_ID = IMAGE_ID = position + 1), images.txt with
// names[i] and an empty points line, and an empty points3D.txt (COLMAP's tools want all three).
// Numbers are written in the shortest form that reads back to the same double.
void writeColmap(const std::string& dir, const std::vector<CameraD>& cameras, const std::vector<std::string>& names,
                 int width, int height);

}  // namespace spar
