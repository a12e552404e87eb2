// COLMAP text models; see colmap.h for the format and the choices made.
#include "formats/colmap.h"

#include <cctype>
#include <charconv>
#include <cstdint>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>

#include "spar/error.h"

namespace spar {
namespace {

namespace fs = std::filesystem;

// One camera model: how many parameters it has and which are fx, fy, cx, cy (SIMPLE_* models
// have one focal length for both axes).
struct Model {
  const char* name;
  int params;
  bool oneFocal;
};
// Distortion follows the pinhole part in every one of these: parameters past the pinhole
// ones (3 with one focal, 4 with two) are distortion.
constexpr Model kModels[] = {
    {"SIMPLE_PINHOLE", 3, true}, {"PINHOLE", 4, false}, {"SIMPLE_RADIAL", 4, true},
    {"RADIAL", 5, true},         {"OPENCV", 8, false},  {"FULL_OPENCV", 12, false},
};
// Known to COLMAP, refused here (see colmap.h).
constexpr const char* kFisheyeModels[] = {"SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE", "OPENCV_FISHEYE", "FOV",
                                          "THIN_PRISM_FISHEYE", "RAD_TAN_THIN_PRISM_FISHEYE"};

struct Camera {
  std::string model;
  int width = 0, height = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0;
  bool distorted = false;  // a non-zero distortion parameter
};

// Lines of one file with their numbers, for "FILE:LINE: ..." errors.
class Lines {
 public:
  explicit Lines(const std::string& path) : path_(path), in_(path, std::ios::binary) {
    if (!in_) throw Error("cannot read " + path + ": cannot open it");
  }
  // The next line (without '\r'); false at the end.
  bool next(std::string& line) {
    if (!std::getline(in_, line)) {
      if (in_.bad()) throw Error("cannot read " + path_ + ": read error");
      return false;
    }
    ++number_;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    return true;
  }
  // The next line that is neither blank nor a comment.
  bool nextData(std::string& line) {
    while (next(line)) {
      const size_t b = line.find_first_not_of(" \t");
      if (b != std::string::npos && line[b] != '#') return true;
    }
    return false;
  }
  [[noreturn]] void fail(const std::string& what) const {
    throw Error(path_ + ":" + std::to_string(number_) + ": " + what);
  }

 private:
  std::string path_;
  std::ifstream in_;
  int number_ = 0;
};

std::vector<std::string> fields(const std::string& line) {
  std::istringstream ss(line);
  std::vector<std::string> out;
  for (std::string f; ss >> f;) out.push_back(f);
  return out;
}

double number(const Lines& at, const std::string& s, const char* what) {
  double v = 0;
  const auto r = std::from_chars(s.data(), s.data() + s.size(), v);
  if (r.ec != std::errc() || r.ptr != s.data() + s.size() || !std::isfinite(v))
    at.fail(std::string(what) + " is not a finite number: " + s);
  return v;
}

uint64_t id(const Lines& at, const std::string& s, const char* what) {
  uint64_t v = 0;
  const auto r = std::from_chars(s.data(), s.data() + s.size(), v);
  if (r.ec != std::errc() || r.ptr != s.data() + s.size()) at.fail(std::string(what) + " is not an id: " + s);
  return v;
}

std::map<uint64_t, Camera> readCamerasTxt(const std::string& path) {
  Lines lines(path);
  std::map<uint64_t, Camera> cams;
  for (std::string line; lines.nextData(line);) {
    const auto f = fields(line);
    if (f.size() < 4) lines.fail("expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[], got " + std::to_string(f.size()) +
                                 " fields");
    const uint64_t cid = id(lines, f[0], "CAMERA_ID");
    const Model* model = nullptr;
    for (const Model& m : kModels)
      if (f[1] == m.name) model = &m;
    if (!model) {
      for (const char* fisheye : kFisheyeModels)
        if (f[1] == fisheye)
          lines.fail("camera model " + f[1] + " is not supported: SPAR renders pinhole cameras (undistort the "
                     "images first, e.g. colmap image_undistorter)");
      lines.fail("unknown camera model " + f[1]);
    }
    if (int(f.size()) != 4 + model->params)
      lines.fail(f[1] + " takes " + std::to_string(model->params) + " parameters, got " +
                 std::to_string(f.size() - 4));
    Camera c;
    c.model = f[1];
    const double w = number(lines, f[2], "WIDTH"), h = number(lines, f[3], "HEIGHT");
    if (w != std::floor(w) || h != std::floor(h) || w < 1 || h < 1 || w > 1e6 || h > 1e6)
      lines.fail("WIDTH, HEIGHT must be image sizes in pixels (1 to 1000000)");
    c.width = int(w);
    c.height = int(h);
    std::vector<double> p;
    for (size_t i = 4; i < f.size(); ++i) p.push_back(number(lines, f[i], "a camera parameter"));
    const size_t k = model->oneFocal ? 1 : 2;  // index of cx
    c.fx = p[0];
    c.fy = p[k - 1];
    c.cx = p[k];
    c.cy = p[k + 1];
    if (!(c.fx > 0) || !(c.fy > 0)) lines.fail("focal lengths must be positive");
    for (size_t i = k + 2; i < p.size(); ++i) c.distorted |= p[i] != 0;
    if (!cams.emplace(cid, c).second) lines.fail("camera " + f[0] + " is defined twice");
  }
  return cams;
}

// Where the two files are, for a directory or the path of images.txt.
std::pair<std::string, std::string> modelFiles(const std::string& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error("COLMAP model not found: " + path);
  if (fs::is_directory(path, ec)) {
    const fs::path d(path);
    if (!fs::exists(d / "images.txt", ec)) {
      if (fs::exists(d / "images.bin", ec))
        throw Error(path + ": a binary COLMAP model; convert it to text first (colmap model_converter "
                    "--output_type TXT)");
      throw Error(path + ": no images.txt (a COLMAP text model is a directory with cameras.txt and images.txt)");
    }
    return {(d / "cameras.txt").string(), (d / "images.txt").string()};
  }
  return {(fs::path(path).parent_path() / "cameras.txt").string(), path};
}

// Shortest text that reads back to the same double (std::to_chars' guarantee).
std::string text(double v) {
  char buf[64];
  const auto r = std::to_chars(buf, buf + sizeof(buf), v);
  return std::string(buf, r.ptr);
}

void writeFile(const fs::path& path, const std::string& content) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f << content;
  f.flush();
  if (!f) throw Error("cannot write " + path.string());
}

}  // namespace

bool isColmapPath(const std::string& path) {
  std::error_code ec;
  return fs::is_directory(path, ec) || fs::path(path).filename() == "images.txt";
}

ColmapCameras readColmap(const std::string& path, int outWidth, int outHeight) {
  const auto [camerasPath, imagesPath] = modelFiles(path);
  std::error_code ec;
  if (!fs::exists(camerasPath, ec)) throw Error(imagesPath + ": no cameras.txt beside it");
  const auto cams = readCamerasTxt(camerasPath);

  struct Image {
    CameraD camera;
    std::string name;
  };
  std::map<uint64_t, Image> images;  // ordered by IMAGE_ID
  std::set<uint64_t> distorted;
  Lines lines(imagesPath);
  for (std::string line; lines.nextData(line);) {
    const auto f = fields(line);
    if (f.size() < 10)
      lines.fail("expected 10 fields (IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME), got " + std::to_string(f.size()));
    const uint64_t iid = id(lines, f[0], "IMAGE_ID");
    std::array<double, 4> q{};
    for (int i = 0; i < 4; ++i) q[i] = number(lines, f[1 + i], "a quaternion component");
    // quatToMat normalizes (COLMAP does too); only no direction at all is meaningless.
    if (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3] < 1e-12) lines.fail("the quaternion is zero");
    double t[3];
    for (int i = 0; i < 3; ++i) t[i] = number(lines, f[5 + i], "a translation component");
    const uint64_t cid = id(lines, f[8], "CAMERA_ID");
    const auto cam = cams.find(cid);
    if (cam == cams.end()) lines.fail("camera " + f[8] + " is not in " + camerasPath);
    // NAME: the rest of the line, so that names with spaces survive.
    size_t pos = 0;
    for (int i = 0; i < 9; ++i) {
      pos = line.find_first_not_of(" \t", pos);
      pos = line.find_first_of(" \t", pos);
    }
    const size_t b = line.find_first_not_of(" \t", pos), e = line.find_last_not_of(" \t");
    Image img;
    img.name = line.substr(b, e - b + 1);

    // c2w = [R^T | -R^T t] of the world-to-camera [R | t].
    const auto r = quatToMat(q);
    Mat4d& m = img.camera.c2w;
    m = Mat4d{};
    m[15] = 1;
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) m[i * 4 + j] = r[j * 3 + i];
      m[i * 4 + 3] = -(r[0 * 3 + i] * t[0] + r[1 * 3 + i] * t[1] + r[2 * 3 + i] * t[2]);
    }
    const Camera& c = cam->second;
    img.camera.k = normalizedIntrinsics(c.fx, c.fy, c.cx, c.cy, c.width, c.height, outWidth, outHeight);
    if (c.distorted) distorted.insert(cid);
    if (!images.emplace(iid, img).second) lines.fail("image " + f[0] + " appears twice");
    // The 2D points line follows each image line (it may be empty); SPAR has no use for it.
    lines.next(line);
  }
  if (images.empty()) throw Error(imagesPath + ": no images");

  ColmapCameras out;
  for (auto& [iid, img] : images) {
    out.cameras.push_back(img.camera);
    out.names.push_back(std::move(img.name));
  }
  if (!distorted.empty()) {
    std::string list;
    for (uint64_t cid : distorted)
      list += (list.empty() ? "" : ", ") + std::to_string(cid) + " (" + cams.at(cid).model + ")";
    out.warning = camerasPath + ": distortion of camera" + (distorted.size() > 1 ? "s " : " ") + list +
                  " ignored: SPAR renders pinhole cameras";
  }
  return out;
}

void writeColmap(const std::string& dir, const std::vector<CameraD>& cameras, const std::vector<std::string>& names,
                 int width, int height) {
  if (cameras.size() != names.size())
    throw Error("COLMAP model " + dir + ": " + std::to_string(cameras.size()) + " cameras for " +
                std::to_string(names.size()) + " names");
  for (const auto& n : names)
    if (n.empty() || n.find_first_of("\r\n") != std::string::npos || std::isspace((unsigned char)n.front()) ||
        std::isspace((unsigned char)n.back()))
      throw Error("COLMAP model " + dir + ": an image name must be one line without surrounding spaces: '" + n + "'");
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) throw Error("cannot create " + dir + ": " + ec.message());

  const std::string n = std::to_string(cameras.size());
  std::string camTxt =
      "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
      "# Number of cameras: " + n + "\n";
  std::string imgTxt =
      "# Image list with two lines of data per image:\n#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
      "#   POINTS2D[] as (X, Y, POINT3D_ID)\n# Number of images: " + n + ", mean observations per image: 0\n";
  for (size_t i = 0; i < cameras.size(); ++i) {
    const CameraD& c = cameras[i];
    const std::string idText = std::to_string(i + 1);
    camTxt += idText + " PINHOLE " + std::to_string(width) + " " + std::to_string(height) + " " +
              text(c.k[0] * width) + " " + text(c.k[1] * height) + " " + text(c.k[2] * width) + " " +
              text(c.k[3] * height) + "\n";
    const Mat4d& m = c.c2w;
    // world-to-camera rotation R = R_c2w^T as a quaternion ...
    const auto q = matToQuat({m[0], m[4], m[8], m[1], m[5], m[9], m[2], m[6], m[10]});
    // ... and t = -R C with the quaternion's own (orthonormal) R, not R_c2w^T: reading computes
    // C = -R^T t from the same R, so the position comes back to rounding even when the c2w
    // rotation was only orthonormal to float precision.
    const auto r = quatToMat(q);
    double t[3];
    for (int i3 = 0; i3 < 3; ++i3)
      t[i3] = -(r[i3 * 3 + 0] * m[3] + r[i3 * 3 + 1] * m[7] + r[i3 * 3 + 2] * m[11]);
    imgTxt += idText + " " + text(q[0]) + " " + text(q[1]) + " " + text(q[2]) + " " + text(q[3]) + " " + text(t[0]) +
              " " + text(t[1]) + " " + text(t[2]) + " " + idText + " " + names[i] + "\n\n";
  }
  const fs::path d(dir);
  writeFile(d / "cameras.txt", camTxt);
  writeFile(d / "images.txt", imgTxt);
  writeFile(d / "points3D.txt",
            "# 3D point list with one line of data per point:\n"
            "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
            "# Number of points: 0, mean track length: 0\n");
}

}  // namespace spar
