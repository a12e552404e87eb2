// Host-side camera math of the `spar` command; see cameras.h. The formulas and their order of
// operations follow reference/spar_reference/cameras.py so that results agree with the
// reference to rounding (the tests compare at 1e-12).
#include "formats/cameras.h"

#include <glm/glm.hpp>
#include <glm/gtc/quaternion.hpp>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <optional>
#include <sstream>

#include "spar/error.h"
#include "imaging/image_prep.h"

namespace spar {
namespace {

using json = nlohmann::json;
using ojson = nlohmann::ordered_json;

// GLM quaternions store (x, y, z, w) but construct as (w, x, y, z); the API uses (w, x, y, z).
glm::dquat toGlm(const std::array<double, 4>& q) { return glm::dquat(q[0], q[1], q[2], q[3]); }
std::array<double, 4> fromGlm(const glm::dquat& q) { return {q.w, q.x, q.y, q.z}; }

// A number from a JSON value as Python's float() takes it from json.load: numbers and numeric
// strings. null counts as absent (the reference would crash on it later). Booleans are refused:
// float(True) works in Python, but a boolean focal length is a mistake, not a value.
std::optional<double> number(const json& obj, const std::string& key, const std::string& where) {
  auto it = obj.find(key);
  if (it == obj.end() || it->is_null()) return std::nullopt;
  if (it->is_number()) return it->get<double>();
  if (it->is_string()) {
    const std::string s = it->get<std::string>();
    char* end = nullptr;
    errno = 0;
    const double v = std::strtod(s.c_str(), &end);
    // Python's float() accepts surrounding whitespace, nothing else.
    while (end && *end && std::isspace(static_cast<unsigned char>(*end))) ++end;
    if (!s.empty() && end && *end == '\0' && errno != ERANGE) return v;
  }
  throw Error(where + ": " + key + " is not a number");
}

// transform_matrix as 4x4 row-major (3x4 gets the row [0 0 0 1]); nullopt if not finite 4x4.
std::optional<Mat4d> matrix(const json& m) {
  if (!m.is_array() || (m.size() != 4 && m.size() != 3)) return std::nullopt;
  Mat4d out{0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1};
  for (size_t r = 0; r < m.size(); ++r) {
    if (!m[r].is_array() || m[r].size() != 4) return std::nullopt;
    for (size_t c = 0; c < 4; ++c) {
      if (!m[r][c].is_number()) return std::nullopt;
      const double v = m[r][c].get<double>();
      if (!std::isfinite(v)) return std::nullopt;
      out[r * 4 + c] = v;
    }
  }
  return out;
}

ojson rows(const double* m, int r, int c) {
  ojson a = ojson::array();
  for (int i = 0; i < r; ++i) {
    ojson row = ojson::array();
    for (int j = 0; j < c; ++j) row.push_back(m[i * c + j]);
    a.push_back(std::move(row));
  }
  return a;
}

}  // namespace

Mat4d flipGlCv(const Mat4d& m) {
  // m @ diag(1, -1, -1, 1): negate columns 1 and 2.
  Mat4d out = m;
  for (int r = 0; r < 4; ++r) {
    out[r * 4 + 1] = -m[r * 4 + 1];
    out[r * 4 + 2] = -m[r * 4 + 2];
  }
  return out;
}

std::vector<CameraD> readTransforms(const std::string& path, int outWidth, int outHeight) {
  std::ifstream in(path, std::ios::binary);
  if (!std::filesystem::exists(path)) throw Error("cameras file not found: " + path);
  if (!in) throw Error("cannot read cameras file " + path + ": cannot open it");
  json data;
  try {
    std::stringstream ss;
    ss << in.rdbuf();
    data = json::parse(ss.str());
  } catch (const std::exception& e) {
    throw Error("cannot read cameras file " + path + ": " + e.what());
  }
  const json* frames = data.is_object() && data.contains("frames") ? &data["frames"] : nullptr;
  if (!frames || !frames->is_array() || frames->empty()) throw Error(path + ": no frames");

  std::vector<CameraD> cams;
  for (size_t i = 0; i < frames->size(); ++i) {
    const json& fr = (*frames)[i];
    const std::string where = path + ": frames[" + std::to_string(i) + "]";
    if (!fr.is_object() || !fr.contains("transform_matrix")) throw Error(where + ": no transform_matrix");
    const auto m = matrix(fr["transform_matrix"]);
    if (!m) throw Error(where + ": transform_matrix is not a finite 4x4 matrix");
    // A frame's own value wins over the top level's, which wins over the default. The top
    // level is read first, as in the reference, so a bad top-level value is an error anyway.
    auto get = [&](const std::string& key, std::optional<double> dflt) -> std::optional<double> {
      const auto top = number(data, key, where);
      const auto own = number(fr, key, where);
      return own ? own : (top ? top : dflt);
    };
    const double w = *get("w", double(outWidth));
    const double h = *get("h", double(outHeight));
    const auto fx = get("fl_x", std::nullopt);
    if (!fx) throw Error(where + ": no fl_x");
    const double fy = *get("fl_y", *fx);
    const double cx = *get("cx", w / 2.0);
    const double cy = *get("cy", h / 2.0);
    if (!(w > 0) || !(h > 0) || !(*fx > 0) || !(fy > 0) || !std::isfinite(w) || !std::isfinite(h) ||
        !std::isfinite(*fx) || !std::isfinite(fy))
      throw Error(where + ": w, h, fl_x, fl_y must be positive");
    if (!std::isfinite(cx) || !std::isfinite(cy)) throw Error(where + ": cx, cy must be finite");
    // Python's int(round(w)): half to even.
    const double rw = std::nearbyint(w), rh = std::nearbyint(h);
    if (rw < 1 || rh < 1 || rw > 1e6 || rh > 1e6)
      throw Error(where + ": w, h must be image sizes in pixels (1 to 1000000)");
    CameraD cam;
    cam.k = normalizedIntrinsics(*fx, fy, cx, cy, w, h, outWidth, outHeight);
    cam.c2w = flipGlCv(*m);
    cams.push_back(cam);
  }
  return cams;
}

std::array<double, 4> normalizedIntrinsics(double fx, double fy, double cx, double cy, double w, double h,
                                           int outWidth, int outHeight) {
  // Python's int(round(w)): half to even.
  const CropGeometry g = cropGeometry(int(std::nearbyint(w)), int(std::nearbyint(h)), outWidth, outHeight);
  const double sx = g.resizedWidth / w, sy = g.resizedHeight / h;
  return {fx * sx / outWidth, fy * sy / outHeight, (cx * sx - g.left) / outWidth, (cy * sy - g.top) / outHeight};
}

RenderCameras toRenderCameras(const std::vector<CameraD>& cameras) {
  RenderCameras rc;
  for (const auto& c : cameras) {
    std::array<float, 16> m{};
    std::array<float, 4> k{};
    for (int i = 0; i < 16; ++i) m[i] = static_cast<float>(c.c2w[i]);
    for (int i = 0; i < 4; ++i) k[i] = static_cast<float>(c.k[i]);
    rc.c2w.push_back(m);
    rc.fxfycxcy.push_back(k);
  }
  return rc;
}

std::vector<CameraD> fromRenderCameras(const RenderCameras& cameras) {
  std::vector<CameraD> out(cameras.size());
  for (size_t j = 0; j < cameras.size(); ++j) {
    for (int i = 0; i < 16; ++i) out[j].c2w[i] = cameras.c2w[j][i];
    for (int i = 0; i < 4; ++i) out[j].k[i] = cameras.fxfycxcy[j][i];
  }
  return out;
}

std::array<double, 4> matToQuat(const std::array<double, 9>& r) {
  auto R = [&](int i, int j) { return r[i * 3 + j]; };
  const double t = R(0, 0) + R(1, 1) + R(2, 2);
  glm::dquat q;
  // Shepperd's method with the reference's branch order (it decides the sign of q).
  if (t > 0) {
    const double s = std::sqrt(t + 1.0) * 2;
    q = glm::dquat(0.25 * s, (R(2, 1) - R(1, 2)) / s, (R(0, 2) - R(2, 0)) / s, (R(1, 0) - R(0, 1)) / s);
  } else if (R(0, 0) > R(1, 1) && R(0, 0) > R(2, 2)) {
    const double s = std::sqrt(1.0 + R(0, 0) - R(1, 1) - R(2, 2)) * 2;
    q = glm::dquat((R(2, 1) - R(1, 2)) / s, 0.25 * s, (R(0, 1) + R(1, 0)) / s, (R(0, 2) + R(2, 0)) / s);
  } else if (R(1, 1) > R(2, 2)) {
    const double s = std::sqrt(1.0 + R(1, 1) - R(0, 0) - R(2, 2)) * 2;
    q = glm::dquat((R(0, 2) - R(2, 0)) / s, (R(0, 1) + R(1, 0)) / s, 0.25 * s, (R(1, 2) + R(2, 1)) / s);
  } else {
    const double s = std::sqrt(1.0 + R(2, 2) - R(0, 0) - R(1, 1)) * 2;
    q = glm::dquat((R(1, 0) - R(0, 1)) / s, (R(0, 2) + R(2, 0)) / s, (R(1, 2) + R(2, 1)) / s, 0.25 * s);
  }
  return fromGlm(q / std::sqrt(glm::dot(q, q)));
}

std::array<double, 9> quatToMat(const std::array<double, 4>& qa) {
  glm::dquat q = toGlm(qa);
  q = q / std::sqrt(glm::dot(q, q));
  const glm::dmat3 m = glm::mat3_cast(q);  // column-major: m[col][row]
  std::array<double, 9> out{};
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) out[r * 3 + c] = m[c][r];
  return out;
}

std::array<double, 4> slerp(const std::array<double, 4>& a, const std::array<double, 4>& b, double u) {
  // Not glm::slerp: its lerp fallback (above 1 - epsilon) does not renormalize and its
  // threshold differs; the reference's is 0.9995 with a normalized lerp.
  const glm::dquat q0 = toGlm(a);
  glm::dquat q1 = toGlm(b);
  double d = glm::dot(q0, q1);
  if (d < 0) {
    q1 = -q1;
    d = -d;
  }
  if (d > 0.9995) {
    const glm::dquat q = q0 + u * (q1 - q0);
    return fromGlm(q / std::sqrt(glm::dot(q, q)));
  }
  const double th = std::acos(std::min(1.0, d));
  return fromGlm((std::sin((1 - u) * th) * q0 + std::sin(u * th) * q1) / std::sin(th));
}

std::vector<Mat4d> interpolatePath(const std::vector<Mat4d>& c2w, int n) {
  if (n < 1) throw Error("a camera path needs at least 1 frame, got " + std::to_string(n));
  if (c2w.empty()) throw Error("a camera path needs at least 1 camera to follow");
  const int k = static_cast<int>(c2w.size());
  std::vector<std::array<double, 4>> quats;
  for (const auto& m : c2w)
    quats.push_back(matToQuat({m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]}));
  std::vector<Mat4d> out;
  for (int j = 0; j < n; ++j) {
    if (k == 1) {
      out.push_back(c2w[0]);
      continue;
    }
    const double t = n == 1 ? 0.0 : static_cast<double>(int64_t(j) * (k - 1)) / static_cast<double>(n - 1);
    const int i = std::min(static_cast<int>(std::floor(t)), k - 2);
    const double u = t - i;
    const auto r = quatToMat(slerp(quats[i], quats[i + 1], u));
    const glm::dvec3 p0(c2w[i][3], c2w[i][7], c2w[i][11]), p1(c2w[i + 1][3], c2w[i + 1][7], c2w[i + 1][11]);
    const glm::dvec3 p = (1 - u) * p0 + u * p1;
    out.push_back({r[0], r[1], r[2], p.x, r[3], r[4], r[5], p.y, r[6], r[7], r[8], p.z, 0, 0, 0, 1});
  }
  return out;
}

ojson cameraEntry(const CameraD& camera, int w, int h, const ojson& extra) {
  ojson e = extra.is_object() ? extra : ojson::object();
  const auto& k = camera.k;
  const Mat4d gl = flipGlCv(camera.c2w);
  e["transform_matrix"] = rows(gl.data(), 4, 4);
  e["fl_x"] = k[0] * w;
  e["fl_y"] = k[1] * h;
  e["cx"] = k[2] * w;
  e["cy"] = k[3] * h;
  e["w"] = w;
  e["h"] = h;
  e["intrinsics_normalized"] = ojson{{"fx", k[0]}, {"fy", k[1]}, {"cx", k[2]}, {"cy", k[3]}};
  e["c2w_opencv"] = rows(camera.c2w.data(), 4, 4);
  return e;
}

std::string absolutePath(const std::string& path) {
  namespace fs = std::filesystem;
  std::string s = fs::absolute(fs::path(path)).lexically_normal().string();
  // normpath drops a trailing separator; lexically_normal keeps one.
  while (s.size() > 1 && s.back() == '/') s.pop_back();
  return s;
}

ojson camerasJson(const CamerasDocument& doc) {
  if (doc.cameras.size() != doc.files.size() || doc.cameras.empty())
    throw Error("cameras.json: " + std::to_string(doc.cameras.size()) + " cameras for " +
                std::to_string(doc.files.size()) + " files");
  auto isInput = [&](int64_t i) { return std::find(doc.inputs.begin(), doc.inputs.end(), i) != doc.inputs.end(); };
  ojson order = ojson::array(), frames = ojson::array();
  for (size_t i = 0; i < doc.files.size(); ++i) {
    const std::string file = absolutePath(doc.files[i]);
    const char* role = isInput(int64_t(i)) ? "input" : "target";
    order.push_back(ojson{{"index", i}, {"file", file}, {"role", role}});
    frames.push_back(cameraEntry(doc.cameras[i], doc.width, doc.height,
                                 ojson{{"file_path", file}, {"index", i}, {"role", role}}));
  }
  ojson d = ojson::object();
  d["camera_model"] = "PINHOLE";
  d["convention"] =
      "nerfstudio: transform_matrix is camera-to-world in OpenGL axes (x right, y up, z back); "
      "c2w_opencv = transform_matrix @ diag(1,-1,-1,1) is SPAR's (x right, y down, z forward); "
      "world = the canonical view's camera; intrinsics in pixels of the model's w x h image, "
      "intrinsics_normalized = (fx/w, fy/h, cx/w, cy/h)";
  d["w"] = doc.width;
  d["h"] = doc.height;
  for (const char* key : {"fl_x", "fl_y", "cx", "cy"}) d[key] = frames[0][key];
  d["canonical_index"] = doc.canonicalIndex;
  d["order"] = std::move(order);
  d["inputs"] = doc.inputs;
  d["targets"] = doc.targets;
  d["frames"] = std::move(frames);
  d["render"] = doc.render;
  if (doc.render != "targets") {
    ojson rf = ojson::array();
    for (size_t j = 0; j < doc.renderCameras.size(); ++j)
      rf.push_back(cameraEntry(doc.renderCameras[j], doc.width, doc.height, ojson{{"index", j}, {"role", "render"}}));
    d["render_frames"] = std::move(rf);
  }
  return d;
}

CameraD estimatedCamera(const Encoded& e, int64_t i) {
  if (i < 0 || size_t(i + 1) * 16 > e.c2w.size() || size_t(i + 1) * 4 > e.fxfycxcy.size())
    throw Error("no estimated camera " + std::to_string(i) + " (" + std::to_string(e.c2w.size() / 16) + " views encoded)");
  CameraD c;
  for (int k = 0; k < 16; ++k) c.c2w[k] = e.c2w[size_t(i) * 16 + k];
  for (int k = 0; k < 4; ++k) c.k[k] = e.fxfycxcy[size_t(i) * 4 + k];
  return c;
}

std::vector<CameraD> inputCameraPath(const Encoded& e, const std::vector<int64_t>& inputs, int n) {
  if (inputs.empty()) throw Error("a camera path needs at least 1 input camera to follow");
  std::vector<Mat4d> c2w;
  for (int64_t i : inputs) c2w.push_back(estimatedCamera(e, i).c2w);
  const auto path = interpolatePath(c2w, n);
  const std::array<double, 4> k = estimatedCamera(e, inputs.front()).k;
  std::vector<CameraD> cams(path.size());
  for (size_t j = 0; j < path.size(); ++j) cams[j] = {path[j], k};
  return cams;
}

}  // namespace spar
