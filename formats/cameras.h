// Camera conventions of the `spar` command, the same as the reference's command-line tool
// (reference/spar_reference/cameras.py):
//
// SPAR's cameras: c2w 4x4 in OpenCV axes (x right, y down, z forward) in the canonical view's
// frame; intrinsics normalized by the model's image size (fx/W, fy/H, cx/W, cy/H).
// nerfstudio transforms.json (what --cameras reads and cameras.json is written in):
// frames[i].transform_matrix is camera-to-world in OpenGL axes (x right, y up, z back);
// fl_x, fl_y, cx, cy, w, h in pixels, top level or per frame (the frame's own value wins).
// c2w_opencv = transform_matrix @ diag(1, -1, -1, 1), and back the same way.
//
// Everything here is host-side double precision (the reference computes these in float64);
// matrices cross the API row-major, as in the JSON files and the pipeline's buffers.
#pragma once
#include <nlohmann/json.hpp>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "spar/request.h"

namespace spar {

using Mat4d = std::array<double, 16>;  // row-major 4x4

struct CameraD {
  Mat4d c2w{};                  // OpenCV camera-to-world
  std::array<double, 4> k{};    // fx/W, fy/H, cx/W, cy/H
};

// The axis flip between OpenGL and OpenCV camera frames (its own inverse): negates the
// y and z columns of the rotation.
Mat4d flipGlCv(const Mat4d& m);

// Reads a nerfstudio transforms.json as cameras.read_transforms does: intrinsics given for a
// w x h image follow the image preparation (cover-resize, centre crop: image_prep.h
// cropGeometry) to the model's outWidth x outHeight and are normalized by it; missing fl_y =
// fl_x, cx, cy = w/2, h/2, w, h = the model size. A 3x4 transform_matrix gets [0 0 0 1].
// Throws spar::Error with one line naming the file and frame ("cameras file not found: P",
// "P: no frames", "P: frames[2]: no fl_x", ...).
std::vector<CameraD> readTransforms(const std::string& path, int outWidth, int outHeight);

// Pixel intrinsics of a w x h image mapped through the image preparation (cropGeometry of
// round(w) x round(h) to outWidth x outHeight) and normalized by the model size: what every
// camera file reader (transforms.json, COLMAP) does with the intrinsics it reads. The caller
// checks that the values are positive and finite and w, h image sizes.
std::array<double, 4> normalizedIntrinsics(double fx, double fy, double cx, double cy, double w, double h,
                                           int outWidth, int outHeight);

// The cameras in the pipeline's single-precision layout.
RenderCameras toRenderCameras(const std::vector<CameraD>& cameras);
// And back (exact: float -> double), so cameras.json holds what was rendered.
std::vector<CameraD> fromRenderCameras(const RenderCameras& cameras);

// Quaternions (w, x, y, z) as the reference computes them: Shepperd's method (the same branch
// order, so the same sign), normalized; quaternion -> matrix; shortest-arc slerp that falls
// back to normalized lerp above a dot product of 0.9995.
std::array<double, 4> matToQuat(const std::array<double, 9>& rowMajor3x3);
std::array<double, 9> quatToMat(const std::array<double, 4>& q);
std::array<double, 4> slerp(const std::array<double, 4>& q0, const std::array<double, 4>& q1, double u);

// N cameras along the given ones, in their order (cameras.interpolate_path): t_j = j (K-1)/(N-1)
// (0 for N = 1); between cameras i and i+1 (i = min(floor t, K-2), u = t - i) the rotation is
// slerp(q_i, q_{i+1}, u) and the position (1-u) t_i + u t_{i+1}. K = 1 repeats that camera.
// Throws spar::Error for N < 1 or no cameras.
std::vector<Mat4d> interpolatePath(const std::vector<Mat4d>& c2w, int n);

// Camera i of an encoded request (the estimated one), in double.
CameraD estimatedCamera(const Encoded& encoded, int64_t i);
// The reference's --path: N cameras along the estimated input cameras (interpolatePath), all
// with the first input's intrinsics. Throws spar::Error for N < 1 or no inputs.
std::vector<CameraD> inputCameraPath(const Encoded& encoded, const std::vector<int64_t>& inputs, int n);

// One frame of cameras.json (cameras.camera_entry): `extra` first (file_path, index, role ...),
// then transform_matrix (OpenGL), fl_x, fl_y, cx, cy (pixels of w x h), w, h,
// intrinsics_normalized {fx, fy, cx, cy}, c2w_opencv. Keys keep this order.
nlohmann::ordered_json cameraEntry(const CameraD& camera, int w, int h,
                                   const nlohmann::ordered_json& extra = nlohmann::ordered_json::object());

// Everything cameras.json holds (Run.cameras_json of the reference).
struct CamerasDocument {
  int width = 0, height = 0;
  std::vector<std::string> files;      // sequence order, written as absolute paths
  std::vector<int64_t> inputs, targets;
  std::vector<CameraD> cameras;        // estimated, one per file
  int64_t canonicalIndex = 0;
  std::string render = "targets";      // "targets" | "path" | "cameras"
  std::vector<CameraD> renderCameras;  // with "path" / "cameras"
};
nlohmann::ordered_json camerasJson(const CamerasDocument& doc);

// The reference's os.path.abspath: absolute and lexically normalized (no symlinks resolved).
std::string absolutePath(const std::string& path);

}  // namespace spar
