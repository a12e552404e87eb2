// model/cameras against the reference's camera functions (reference/spar_reference/cameras.py:
// mat_to_quat, quat_to_mat, slerp, interpolate_path, camera_entry, read_transforms) in float64:
// tests/python/make_path_golden.py writes the inputs, the reference's outputs and the
// transforms.json files it read; both sides compute in double, so they agree to rounding.
// The suite is named "cameras" so that `ctest -R cameras` selects it.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include "spar/error.h"
#include "formats/cameras.h"
#include "tests/golden_support.h"

namespace spar {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::ordered_json;  // keeps the reference's key order
constexpr double kTol = 1e-12;

// tests/python/make_path_golden.py's cases (fixture op_goldens, made once per build).
const json& golden(const char* section) {
  static const json all = [] {
    const std::string path = test::opGoldenPath("path/golden.json");
    std::ifstream in(path);
    if (!in) throw Error(path + ": cannot open (did the op_goldens fixture run?)");
    return json::parse(in);
  }();
  return all.at(section);
}

Mat4d mat4(const json& m) {
  Mat4d out{};
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) out[r * 4 + c] = m.at(r).at(c).get<double>();
  return out;
}

template <class A, class B>
double maxDiff(const A& a, const B& b) {
  double d = 0;
  for (size_t i = 0; i < a.size(); ++i) d = std::max(d, std::abs(double(a[i]) - double(b[i])));
  return d;
}

TEST(cameras, MatToQuatEveryShepperdBranch) {
  for (const auto& c : golden("quat")) {
    std::array<double, 9> r{};
    for (int i = 0; i < 9; ++i) r[i] = c["r"][i / 3][i % 3].get<double>();
    const auto q = matToQuat(r);
    const auto want = c["q"].get<std::array<double, 4>>();
    EXPECT_LE(maxDiff(q, want), kTol) << c["name"];  // same sign too: same branch order
    EXPECT_LE(maxDiff(quatToMat(q), r), 1e-12) << c["name"] << " round trip";
  }
}

TEST(cameras, SlerpIncludingIdenticalAndOppositeQuaternions) {
  for (const auto& c : golden("slerp")) {
    const auto q = slerp(c["q0"].get<std::array<double, 4>>(), c["q1"].get<std::array<double, 4>>(),
                         c["u"].get<double>());
    for (double v : q) EXPECT_TRUE(std::isfinite(v)) << c["name"];
    EXPECT_LE(maxDiff(q, c["q"].get<std::array<double, 4>>()), kTol) << c["name"];
  }
}

// Random, N = 1, N = 2, K = 1, identical cameras, rotations near 180 degrees, both sides of the
// lerp threshold, opposite hemispheres, large translations.
TEST(cameras, InterpolatePathMatchesReference) {
  int cases = 0;
  for (const auto& c : golden("path")) {
    std::vector<Mat4d> in;
    for (const auto& m : c["c2w"]) in.push_back(mat4(m));
    const int n = c["n"].get<int>();
    const auto out = interpolatePath(in, n);
    ASSERT_EQ(out.size(), size_t(n)) << c["name"];
    double err = 0;
    for (int j = 0; j < n; ++j) {
      const Mat4d want = mat4(c["out"][j]);
      // translations up to 2e3: relative for them
      for (int i = 0; i < 16; ++i)
        err = std::max(err, std::abs(out[j][i] - want[i]) / std::max(1.0, std::abs(want[i])));
      for (double v : out[j]) ASSERT_TRUE(std::isfinite(v)) << c["name"];
    }
    EXPECT_LE(err, kTol) << c["name"];
    std::printf("  path %-18s K=%zu N=%d max err %.2e\n", c["name"].get<std::string>().c_str(), in.size(), n, err);
    ++cases;
  }
  EXPECT_GE(cases, 10);
}

TEST(cameras, PathEndpointsAreTheCameras) {
  const auto& c = golden("path")[0];
  std::vector<Mat4d> in;
  for (const auto& m : c["c2w"]) in.push_back(mat4(m));
  const auto out = interpolatePath(in, 7);
  EXPECT_LE(maxDiff(out.front(), in.front()), 1e-12);
  EXPECT_LE(maxDiff(out.back(), in.back()), 1e-12);
}

TEST(cameras, PathRefusesNoFrames) {
  EXPECT_THROW(interpolatePath({Mat4d{}}, 0), Error);
  EXPECT_THROW(interpolatePath({}, 3), Error);
}

TEST(cameras, CameraEntrySameKeysOrderAndValues) {
  for (const auto& c : golden("entry")) {
    CameraD cam;
    cam.c2w = mat4(c["c2w"]);
    cam.k = c["k"].get<std::array<double, 4>>();
    const auto e = cameraEntry(cam, c["w"].get<int>(), c["h"].get<int>(), c["extra"]);
    // Key order as the reference writes it (json.dump keeps insertion order).
    const json& want = c["out"];
    std::vector<std::string> keys, wantKeys;
    for (auto it = e.begin(); it != e.end(); ++it) keys.push_back(it.key());
    for (auto it = want.begin(); it != want.end(); ++it) wantKeys.push_back(it.key());
    EXPECT_EQ(keys, wantKeys);
    // Values: the flattened documents agree key by key.
    const json a = e.flatten(), b = want.flatten();
    ASSERT_EQ(a.size(), b.size());
    for (auto it = b.begin(); it != b.end(); ++it) {
      ASSERT_TRUE(a.contains(it.key())) << it.key();
      if (it->is_number())
        EXPECT_NEAR(a[it.key()].get<double>(), it->get<double>(), 1e-12) << it.key();
      else
        EXPECT_EQ(a[it.key()], *it) << it.key();
    }
  }
}

TEST(cameras, ReadTransformsMatchesReference) {
  int good = 0;
  for (const auto& c : golden("transforms")) {
    if (c.contains("error")) continue;
    const auto cams = readTransforms(c["file"], c["out_w"], c["out_h"]);
    ASSERT_EQ(cams.size(), c["k"].size()) << c["name"];
    for (size_t j = 0; j < cams.size(); ++j) {
      EXPECT_LE(maxDiff(cams[j].c2w, mat4(c["c2w"][j])), 0.0) << c["name"];  // a sign flip: exact
      EXPECT_LE(maxDiff(cams[j].k, c["k"][j].get<std::array<double, 4>>()), kTol) << c["name"];
    }
    ++good;
  }
  EXPECT_GE(good, 16);
}

// Every file the reference refuses is refused, with one line naming the file; where the
// reference raised its own CameraError the text is the same.
TEST(cameras, ReadTransformsRefusesBadFiles) {
  int bad = 0;
  for (const auto& c : golden("transforms")) {
    if (!c.contains("error")) continue;
    const std::string file = c["file"];
    try {
      readTransforms(file, c["out_w"], c["out_h"]);
      ADD_FAILURE() << c["name"] << ": accepted, the reference said: " << c["error"];
    } catch (const Error& e) {
      const std::string msg = e.what();
      EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
      EXPECT_NE(msg.find(file), std::string::npos) << msg;
      if (c["exact"].get<bool>()) {
        EXPECT_EQ(msg, c["error"].get<std::string>()) << c["name"];
      } else {
        EXPECT_EQ(msg.rfind(c["prefix"].get<std::string>(), 0), 0u) << msg;
      }
      std::printf("  %-18s %s\n", c["name"].get<std::string>().c_str(), msg.c_str());
    }
    ++bad;
  }
  EXPECT_GE(bad, 20);
}

TEST(cameras, RenderCamerasRoundTrip) {
  const auto& c = golden("path")[0];
  std::vector<CameraD> cams(2);
  cams[0].c2w = mat4(c["c2w"][0]);
  cams[1].c2w = mat4(c["c2w"][1]);
  cams[0].k = {1.25, 1.25, 0.5, 0.5};
  cams[1].k = {0.3, 0.4, 0.45, 0.55};
  const RenderCameras rc = toRenderCameras(cams);
  ASSERT_EQ(rc.size(), 2u);
  const auto back = fromRenderCameras(rc);
  for (size_t j = 0; j < 2; ++j) {
    EXPECT_LE(maxDiff(back[j].c2w, cams[j].c2w), 1e-6);
    EXPECT_EQ(back[j].k[1], double(float(cams[j].k[1])));
  }
}

TEST(cameras, CamerasJsonDocument) {
  CamerasDocument doc;
  doc.width = 128;
  doc.height = 96;
  doc.files = {"a.png", "./sub/../b.png", "/abs/c.png"};
  doc.inputs = {0, 2};
  doc.targets = {1};
  doc.canonicalIndex = 1;
  for (int i = 0; i < 3; ++i) {
    CameraD cam;
    cam.c2w = Mat4d{1, 0, 0, double(i), 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    cam.k = {1.25, 1.25, 0.5, 0.5};
    doc.cameras.push_back(cam);
  }
  auto j = camerasJson(doc);
  EXPECT_EQ(j["render"], "targets");
  EXPECT_FALSE(j.contains("render_frames"));
  EXPECT_EQ(j["fl_x"].get<double>(), 160.0);
  EXPECT_EQ(j["fl_y"].get<double>(), 120.0);
  EXPECT_EQ(j["order"][1]["file"], (fs::current_path() / "b.png").string());
  EXPECT_EQ(j["order"][2]["file"], "/abs/c.png");
  EXPECT_EQ(j["order"][1]["role"], "target");
  EXPECT_EQ(j["frames"][2]["role"], "input");
  EXPECT_EQ(j["frames"][1]["transform_matrix"][1][1].get<double>(), -1.0);  // OpenGL axes
  EXPECT_EQ(j["inputs"], nlohmann::ordered_json({0, 2}));
  doc.render = "path";
  doc.renderCameras = {doc.cameras[0]};
  j = camerasJson(doc);
  ASSERT_EQ(j["render_frames"].size(), 1u);
  EXPECT_EQ(j["render_frames"][0]["role"], "render");
  std::vector<std::string> keys;
  for (auto it = j.begin(); it != j.end(); ++it) keys.push_back(it.key());
  EXPECT_EQ(keys, (std::vector<std::string>{"camera_model", "convention", "w", "h", "fl_x", "fl_y", "cx", "cy",
                                            "canonical_index", "order", "inputs", "targets", "frames", "render",
                                            "render_frames"}));
}

}  // namespace
}  // namespace spar
