// formats/colmap: COLMAP text models in and out (host only).
//  - write -> read is exact (the bar is 1e-6; in double it holds to 1e-12) on random
//    rotations and the stiff ones: identity, near-identity, 180-degree turns (quaternion w = 0),
//    w near 0, rotations whose Shepperd branch gives a negative w; float-precision cameras (what
//    SPAR renders) within 1e-6.
//  - hand-written files with known values read to the expected c2w and normalized intrinsics.
//  - malformed files: one line naming the file and line.
// The suite is named "colmap" so that `ctest -R colmap` selects it.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "spar/error.h"
#include "formats/colmap.h"
#include "tests/test_support.h"

namespace spar {
namespace {

namespace fs = std::filesystem;
using Quat = std::array<double, 4>;

const fs::path& scratch() { return test::scratchDir("colmap"); }

// A c2w from a rotation (as a quaternion) and a camera position.
Mat4d pose(const Quat& q, double x, double y, double z) {
  const auto r = quatToMat(q);
  return {r[0], r[1], r[2], x, r[3], r[4], r[5], y, r[6], r[7], r[8], z, 0, 0, 0, 1};
}

Quat axisAngle(double ax, double ay, double az, double angle) {
  const double n = std::sqrt(ax * ax + ay * ay + az * az), s = std::sin(angle / 2) / n;
  return {std::cos(angle / 2), ax * s, ay * s, az * s};
}

void writeText(const fs::path& p, const std::string& s) {
  fs::create_directories(p.parent_path());
  std::ofstream(p, std::ios::binary) << s;
}

// A model directory with these two files.
std::string model(const std::string& name, const std::string& cameras, const std::string& images) {
  const fs::path d = scratch() / name;
  fs::remove_all(d);
  writeText(d / "cameras.txt", cameras);
  writeText(d / "images.txt", images);
  return d.string();
}

double maxDiff(const Mat4d& a, const Mat4d& b) {
  double d = 0;
  for (int i = 0; i < 16; ++i) d = std::max(d, std::abs(a[i] - b[i]));
  return d;
}
double maxDiff(const std::array<double, 4>& a, const std::array<double, 4>& b) {
  double d = 0;
  for (int i = 0; i < 4; ++i) d = std::max(d, std::abs(a[i] - b[i]));
  return d;
}

struct Named {
  std::string name;
  CameraD camera;
};

std::vector<Named> stiffAndRandomCameras() {
  const double pi = std::acos(-1.0);
  std::vector<Named> out;
  auto add = [&](const std::string& name, const Quat& q, double x, double y, double z,
                 std::array<double, 4> k = {1.25, 1.25, 0.5, 0.5}) {
    out.push_back({name, CameraD{pose(q, x, y, z), k}});
  };
  add("identity", {1, 0, 0, 0}, 0, 0, 0);
  add("near_identity", axisAngle(0.3, -0.5, 0.8, 1e-9), 1e-3, 2e-3, -1e-3);
  add("x_180", {0, 1, 0, 0}, 0, 0, 5);
  add("y_180", {0, 0, 1, 0}, 1, 0, 0);
  add("z_180", {0, 0, 0, 1}, 0, -2, 0);
  add("diag_180", {0, std::sqrt(0.5), std::sqrt(0.5), 0}, 0.5, 0.5, 0.5);  // trace -1, w = 0
  add("w_near_0", axisAngle(1, 2, 3, pi - 1e-7), -3, 4, 1);
  add("w_negative", {-0.2, 0.5, -0.7, 0.3}, 2, 2, 2);  // the same rotation as +q
  add("far", axisAngle(-1, 1, 0.2, 2.0), 1e3, -2e3, 5e2, {0.3, 2.5, 0.45, 0.55});
  std::mt19937_64 rng(20260101);
  std::normal_distribution<double> g;
  std::uniform_real_distribution<double> u(0.2, 3.0), c(0.3, 0.7);
  for (int i = 0; i < 200; ++i) {
    // A Gaussian 4-vector normalized is a uniform random rotation.
    const Quat q{g(rng), g(rng), g(rng), g(rng)};
    add("random_" + std::to_string(i), q, 10 * g(rng), 10 * g(rng), 10 * g(rng), {u(rng), u(rng), c(rng), c(rng)});
  }
  return out;
}

ColmapCameras roundTrip(const std::string& dirName, const std::vector<CameraD>& cams, int w, int h,
                        std::vector<std::string> names = {}) {
  if (names.empty())
    for (size_t i = 0; i < cams.size(); ++i) names.push_back("view_" + std::to_string(i) + ".png");
  const std::string dir = (scratch() / dirName).string();
  fs::remove_all(dir);
  writeColmap(dir, cams, names, w, h);
  return readColmap(dir, w, h);
}

TEST(colmap, RoundTripIsExactIncludingStiffRotations) {
  const auto cases = stiffAndRandomCameras();
  std::vector<CameraD> cams;
  for (const auto& c : cases) cams.push_back(c.camera);
  const int w = 160, h = 96;
  const ColmapCameras back = roundTrip("round_trip", cams, w, h);
  ASSERT_EQ(back.cameras.size(), cams.size());
  EXPECT_EQ(back.warning, "");
  double worstR = 0, worstT = 0, worstK = 0;
  for (size_t j = 0; j < cams.size(); ++j) {
    const Mat4d &a = back.cameras[j].c2w, &b = cams[j].c2w;
    double dr = 0, dt = 0;
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) {
        const double d = std::abs(a[r * 4 + c] - b[r * 4 + c]);
        if (c == 3) dt = std::max(dt, d / std::max(1.0, std::abs(b[r * 4 + c])));  // relative for 2e3
        else dr = std::max(dr, d);
      }
    const double dk = maxDiff(back.cameras[j].k, cams[j].k);
    EXPECT_LE(dr, 1e-12) << cases[j].name;
    EXPECT_LE(dt, 1e-12) << cases[j].name;
    EXPECT_LE(dk, 1e-12) << cases[j].name;
    EXPECT_EQ(back.names[j], "view_" + std::to_string(j) + ".png");
    worstR = std::max(worstR, dr);
    worstT = std::max(worstT, dt);
    worstK = std::max(worstK, dk);
  }
  std::printf("  %zu cameras: max error rotation %.2e, position (relative) %.2e, intrinsics %.2e\n", cams.size(),
              worstR, worstT, worstK);
}

// What spar render writes: float cameras (rotations orthonormal only to float precision).
TEST(colmap, RoundTripOfFloatCamerasWithin1e6) {
  std::vector<CameraD> cams;
  for (const auto& c : stiffAndRandomCameras()) cams.push_back(c.camera);
  cams = fromRenderCameras(toRenderCameras(cams));
  const ColmapCameras back = roundTrip("round_trip_float", cams, 128, 128);
  double worst = 0;
  for (size_t j = 0; j < cams.size(); ++j) {
    // positions relative to their size, as float holds them
    Mat4d a = back.cameras[j].c2w, b = cams[j].c2w;
    for (int r = 0; r < 3; ++r) {
      const double s = std::max(1.0, std::abs(b[r * 4 + 3]));
      a[r * 4 + 3] /= s;
      b[r * 4 + 3] /= s;
    }
    const double d = std::max(maxDiff(a, b), maxDiff(back.cameras[j].k, cams[j].k));
    EXPECT_LE(d, 1e-6) << j;
    worst = std::max(worst, d);
  }
  std::printf("  float cameras: max error %.2e\n", worst);
}

// Views come back in IMAGE_ID order, which the writer makes the given order, whatever the names.
TEST(colmap, OrderIsImageIdNotName) {
  std::vector<CameraD> cams(3);
  for (int i = 0; i < 3; ++i) cams[i] = CameraD{pose({1, 0, 0, 0}, i, 0, 0), {1, 1, 0.5, 0.5}};
  const auto back = roundTrip("order", cams, 64, 64, {"z.png", "a.png", "sub/m y.png"});
  EXPECT_EQ(back.names, (std::vector<std::string>{"z.png", "a.png", "sub/m y.png"}));
  for (int i = 0; i < 3; ++i) EXPECT_EQ(back.cameras[i].c2w[3], double(i));
}

TEST(colmap, WrittenFilesAreCOLMAPText) {
  std::vector<CameraD> cams{CameraD{pose({1, 0, 0, 0}, 1, 2, 3), {1.25, 1.0, 0.5, 0.25}}};
  const fs::path d = scratch() / "written";
  fs::remove_all(d);
  writeColmap(d.string(), cams, {"a.png"}, 128, 96);
  auto data = [](const fs::path& p) {
    std::ifstream in(p);
    std::vector<std::string> lines;
    for (std::string l; std::getline(in, l);)
      if (l.empty() || l[0] != '#') lines.push_back(l);
    return lines;
  };
  EXPECT_EQ(data(d / "cameras.txt"), (std::vector<std::string>{"1 PINHOLE 128 96 160 96 64 24"}));
  // identity: w2c t = -C; then the empty 2D points line
  EXPECT_EQ(data(d / "images.txt"), (std::vector<std::string>{"1 1 0 0 0 -1 -2 -3 1 a.png", ""}));
  EXPECT_TRUE(fs::exists(d / "points3D.txt"));
  EXPECT_TRUE(data(d / "points3D.txt").empty());
  EXPECT_THROW(writeColmap(d.string(), cams, {"a\nb.png"}, 128, 96), Error);
  EXPECT_THROW(writeColmap(d.string(), cams, {}, 128, 96), Error);
}

// Known values by hand: the model is 128 wide, 96 high.
TEST(colmap, HandWrittenModelReadsToKnownCameras) {
  const std::string dir = model("hand",
                                "# Camera list\n"
                                "1 PINHOLE 640 480 500 400 320 240\r\n"  // CRLF too
                                "\n"
                                "2 SIMPLE_PINHOLE 128 128 100 64 60\n",
                                "# Image list\n"
                                "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
                                "7 1 0 0 0 1 2 3 2 second.png\n"
                                "\n"
                                "3 0 2 0 0 0 0 5 1 first.png\n"  // not unit: normalized
                                "10.5 20.5 -1 11.0 3.0 4\n"
                                "9 -1 0 0 0 0 0 0 1 my photo.png\n"
                                "\n");
  const ColmapCameras m = readColmap(dir, 128, 96);
  ASSERT_EQ(m.cameras.size(), 3u);
  EXPECT_EQ(m.names, (std::vector<std::string>{"first.png", "second.png", "my photo.png"}));
  // 640x480 -> 128x96: scale 0.2, no crop.
  EXPECT_LE(maxDiff(m.cameras[0].k, {500 * 0.2 / 128, 400 * 0.2 / 96, 0.5, 0.5}), 1e-15);
  // 180 degrees about x: R = diag(1, -1, -1), C = -R^T t = (0, 0, 5).
  EXPECT_LE(maxDiff(m.cameras[0].c2w, {1, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 5, 0, 0, 0, 1}), 1e-15);
  // 128x128 -> 128x96: no resize, 16 rows cropped off the top.
  EXPECT_LE(maxDiff(m.cameras[1].k, {100.0 / 128, 100.0 / 96, 64.0 / 128, (60.0 - 16) / 96}), 1e-15);
  EXPECT_LE(maxDiff(m.cameras[1].c2w, {1, 0, 0, -1, 0, 1, 0, -2, 0, 0, 1, -3, 0, 0, 0, 1}), 1e-15);
  // w = -1: the identity as well
  EXPECT_LE(maxDiff(m.cameras[2].c2w, pose({1, 0, 0, 0}, 0, 0, 0)), 1e-15);
  // The same by the path of images.txt.
  const ColmapCameras f = readColmap(dir + "/images.txt", 128, 96);
  EXPECT_EQ(f.names, m.names);
}

TEST(colmap, DistortionIsDroppedWithOneWarningLine) {
  const std::string images = "1 1 0 0 0 0 0 0 1 a.png\n\n2 1 0 0 0 0 0 0 2 b.png\n\n3 1 0 0 0 0 0 0 3 c.png\n\n";
  const std::string dir = model("distorted",
                                "1 OPENCV 128 96 100 90 64 48 0.1 0 0 0\n"
                                "2 SIMPLE_RADIAL 128 96 100 64 48 -0.05\n"
                                "3 RADIAL 128 96 100 64 48 0 0\n",  // zero distortion: nothing dropped
                                images);
  const ColmapCameras m = readColmap(dir, 128, 96);
  EXPECT_EQ(m.warning.find('\n'), std::string::npos);
  EXPECT_NE(m.warning.find("cameras 1 (OPENCV), 2 (SIMPLE_RADIAL) ignored"), std::string::npos) << m.warning;
  EXPECT_LE(maxDiff(m.cameras[0].k, {100.0 / 128, 90.0 / 96, 0.5, 0.5}), 1e-15);
  EXPECT_LE(maxDiff(m.cameras[1].k, {100.0 / 128, 100.0 / 96, 0.5, 0.5}), 1e-15);
  std::printf("  warning: %s\n", m.warning.c_str());
  const std::string clean = model("undistorted", "1 OPENCV 128 96 100 90 64 48 0 0 0 0\n2 FULL_OPENCV 128 96 100 90 "
                                  "64 48 0 0 0 0 0 0 0 0\n3 PINHOLE 128 96 1 1 1 1\n", images);
  EXPECT_EQ(readColmap(clean, 128, 96).warning, "");
}

TEST(colmap, MalformedFilesAreOneLineErrors) {
  const std::string goodCams = "# c\n1 PINHOLE 128 96 100 100 64 48\n";
  const std::string goodImage = "1 1 0 0 0 0 0 0 1 a.png\n\n";
  struct Bad {
    std::string name, cameras, images, says;
  };
  const std::vector<Bad> cases = {
      {"short_image_line", goodCams, "# i\n# i\n1 1 0 0 0 0 0 1 a.png\n\n", "images.txt:3: expected 10 fields"},
      {"unknown_model", "1 PINHOL 128 96 1 1 1 1\n", goodImage, "cameras.txt:1: unknown camera model PINHOL"},
      {"fisheye", "\n1 OPENCV_FISHEYE 128 96 1 1 1 1 0 0 0 0\n", goodImage,
       "cameras.txt:2: camera model OPENCV_FISHEYE is not supported"},
      {"param_count", "1 PINHOLE 128 96 100 100 64\n", goodImage, "cameras.txt:1: PINHOLE takes 4 parameters, got 3"},
      {"short_camera_line", "1 PINHOLE 128\n", goodImage, "cameras.txt:1: expected CAMERA_ID MODEL WIDTH HEIGHT"},
      {"not_a_number", goodCams, "1 1 0 abc 0 0 0 0 1 a.png\n\n", "images.txt:1: a quaternion component is not"},
      {"infinite", goodCams, "1 1 0 0 0 inf 0 0 1 a.png\n\n", "images.txt:1: a translation component is not"},
      {"bad_id", goodCams, "x1 1 0 0 0 0 0 0 1 a.png\n\n", "images.txt:1: IMAGE_ID is not an id"},
      {"missing_camera", goodCams, "1 1 0 0 0 0 0 0 4 a.png\n\n", "images.txt:1: camera 4 is not in"},
      {"image_twice", goodCams, goodImage + goodImage, "images.txt:3: image 1 appears twice"},
      {"camera_twice", goodCams + goodCams, goodImage, "cameras.txt:4: camera 1 is defined twice"},
      {"zero_quaternion", goodCams, "1 0 0 0 0 0 0 0 1 a.png\n\n", "images.txt:1: the quaternion is zero"},
      {"negative_focal", "1 PINHOLE 128 96 -100 100 64 48\n", goodImage, "cameras.txt:1: focal lengths"},
      {"fractional_width", "1 PINHOLE 128.5 96 100 100 64 48\n", goodImage, "cameras.txt:1: WIDTH, HEIGHT"},
      {"zero_height", "1 PINHOLE 128 0 100 100 64 48\n", goodImage, "cameras.txt:1: WIDTH, HEIGHT"},
      {"no_images", goodCams, "# nothing\n\n", "images.txt: no images"},
  };
  for (const auto& c : cases) {
    const std::string dir = model("bad_" + c.name, c.cameras, c.images);
    try {
      readColmap(dir, 128, 96);
      ADD_FAILURE() << c.name << ": accepted";
    } catch (const Error& e) {
      const std::string msg = e.what();
      EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
      EXPECT_EQ(msg.rfind(dir + "/", 0), 0u) << c.name << ": does not name the file: " << msg;
      EXPECT_NE(msg.find(c.says), std::string::npos) << c.name << ": " << msg;
      std::printf("  %-18s %s\n", c.name.c_str(), msg.c_str());
    }
  }
}

TEST(colmap, MissingFilesAreOneLineErrors) {
  const fs::path d = scratch() / "missing";
  fs::remove_all(d);
  fs::create_directories(d / "empty");
  fs::create_directories(d / "binary");
  writeText(d / "binary" / "images.bin", "x");
  writeText(d / "only_images" / "images.txt", "1 1 0 0 0 0 0 0 1 a.png\n\n");
  const std::vector<std::pair<std::string, std::string>> cases = {
      {(d / "nope").string(), "COLMAP model not found: "},
      {(d / "empty").string(), "empty: no images.txt"},
      {(d / "binary").string(), "binary: a binary COLMAP model"},
      {(d / "only_images").string(), "only_images/images.txt: no cameras.txt beside it"},
      {(d / "only_images" / "images.txt").string(), "only_images/images.txt: no cameras.txt beside it"},
  };
  for (const auto& [path, says] : cases) {
    try {
      readColmap(path, 128, 96);
      ADD_FAILURE() << path << ": accepted";
    } catch (const Error& e) {
      const std::string msg = e.what();
      EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
      EXPECT_NE(msg.find(says), std::string::npos) << msg;
      std::printf("  %s\n", msg.c_str());
    }
  }
}

TEST(colmap, WhatCountsAsAColmapPath) {
  const fs::path d = scratch() / "kind";
  fs::create_directories(d);
  EXPECT_TRUE(isColmapPath(d.string()));
  EXPECT_TRUE(isColmapPath((d / "images.txt").string()));  // need not exist yet: readColmap says so
  EXPECT_FALSE(isColmapPath((d / "transforms.json").string()));
  EXPECT_FALSE(isColmapPath((d / "cameras.txt").string()));
}

}  // namespace
}  // namespace spar
