#include "samples/spar_cli/render_outputs.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include "engine/error.h"
#include "formats/colmap.h"
#include "imaging/float_image.h"
#include "imaging/image_prep.h"
#include "model/label_maps.h"
#include "imaging/label_outputs.h"
#include "formats/npy.h"
#include "samples/spar_cli/path_animation.h"

namespace spar::cli {

namespace {

std::string numbered(const std::string& dir, const char* stem, int64_t j, const char* ext = "png") {
  char name[64];
  std::snprintf(name, sizeof(name), "%s_%02lld.%s", stem, static_cast<long long>(j), ext);
  return (std::filesystem::path(dir) / name).string();
}

// COLMAP's NAME is relative to an image folder: the file names, unless two inputs share one
// (then the absolute paths, which cannot be confused).
std::vector<std::string> colmapNames(const std::vector<std::string>& files) {
  std::vector<std::string> names;
  for (const auto& f : files) names.push_back(std::filesystem::path(f).filename().string());
  std::vector<std::string> sorted = names;
  std::sort(sorted.begin(), sorted.end());
  if (std::adjacent_find(sorted.begin(), sorted.end()) == sorted.end()) return names;
  names.clear();
  for (const auto& f : files) names.push_back(absolutePath(f));
  return names;
}

// colmap/: every view's estimated camera, named by its file; with --path / --cameras also
// colmap_render/: the rendered cameras, named by their view_XX.png. Two models, not one,
// because each then matches one folder of images (the inputs', or this directory's views).
int writeColmapModels(const std::string& dir, const CamerasDocument& doc) {
  namespace fs = std::filesystem;
  writeColmap((fs::path(dir) / "colmap").string(), doc.cameras, colmapNames(doc.files), doc.width, doc.height);
  if (doc.renderCameras.empty()) return 3;
  std::vector<std::string> views;
  for (size_t j = 0; j < doc.renderCameras.size(); ++j)
    views.push_back(numbered("", "view", int64_t(j)));  // "" / name: the bare file name
  writeColmap((fs::path(dir) / "colmap_render").string(), doc.renderCameras, views, doc.width, doc.height);
  return 6;
}

}  // namespace

void writeJson(const std::string& path, const nlohmann::ordered_json& doc) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    if (!f) throw Error("cannot write " + tmp);
    f << doc.dump(1) << "\n";
    f.flush();
    if (!f) throw Error("cannot write " + tmp);
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) throw Error("cannot rename " + tmp + " to " + path + ": " + ec.message());
}

int writeRenderOutputs(const std::string& dir, const RenderResult& r) {
  const size_t plane = size_t(r.width) * r.height;
  int files = 0;
  if (r.rgb.size() != size_t(r.rendered) * 3 * plane) throw Error("render result: wrong number of RGB values");
  if (r.motion.size() != size_t(r.motionViews) * plane) throw Error("render result: wrong number of motion values");
  for (int64_t j = 0; j < r.rendered; ++j, ++files) {
    const float* view = r.rgb.data() + size_t(j) * 3 * plane;
    if (r.viewFormat == "png") {
      writePng(numbered(dir, "view", j), view, 3, r.height, r.width);
    } else if (r.viewFormat == "exr" || r.viewFormat == "exr16") {
      writeExr(numbered(dir, "view", j, "exr"), view, 3, r.height, r.width, r.viewFormat == "exr16");
    } else if (r.viewFormat == "npy") {
      writeNpy(numbered(dir, "view", j, "npy"), {3, r.height, r.width}, view);
    } else {
      throw Error("unknown view format '" + r.viewFormat + "' (png, exr, exr16, npy)");
    }
  }
  std::vector<float> mask(plane);
  for (int64_t j = 0; j < r.motionViews; ++j) {
    const float* p = r.motion.data() + size_t(j) * plane;
    writePng(numbered(dir, "motion", j), p, 1, r.height, r.width);
    // The reference's binary mask: prob > threshold, written as 0 / 255.
    for (size_t i = 0; i < plane; ++i) mask[i] = p[i] > r.maskThreshold ? 1.0f : 0.0f;
    writePng(numbered(dir, "mask", j), mask.data(), 1, r.height, r.width);
    files += 2;
  }
  writeJson((std::filesystem::path(dir) / "cameras.json").string(), camerasJson(r.cameras));
  ++files;
  files += writeColmapModels(dir, r.cameras);
  for (size_t j = 0; j < r.labelMaps.size(); ++j) {
    writeLabelPng(numbered(dir, "labels", int64_t(j)), r.labelMaps[j], r.labelHeight, r.labelWidth, r.labels, r.height,
                  r.width);
    writeLabelJson(numbered(dir, "labels", int64_t(j), "json"),
                   labelJson(r.labelMaps[j], r.labelHeight, r.labelWidth, r.labels, int64_t(j), kLsegLogitScale));
    files += 2;
  }
  if (!r.scores.empty()) {
    const int64_t p = int64_t(r.labels.size()), per = p * r.labelHeight * r.labelWidth;
    if (r.scores.size() != size_t(r.rendered * per)) throw Error("render result: wrong number of score values");
    for (int64_t j = 0; j < r.rendered; ++j, ++files)
      writeNpy(numbered(dir, "scores", j, "npy"), {p, r.labelHeight, r.labelWidth}, r.scores.data() + j * per);
  }
  if (!r.features.empty()) {
    const int64_t h = r.height / 2, w = r.width / 2, per = r.featureChannels * h * w;
    if (r.features.size() != size_t(r.rendered * per)) throw Error("render result: wrong number of feature values");
    for (int64_t j = 0; j < r.rendered; ++j, ++files)
      writeNpy(numbered(dir, "features", j, "npy"), {r.featureChannels, h, w}, r.features.data() + j * per);
  }
  if (r.animationFps > 0) {
    writeAnimatedGif((std::filesystem::path(dir) / "path.gif").string(), animationFrames(r), r.animationFps);
    ++files;
  }
  return files;
}

std::vector<RgbImage> animationFrames(const RenderResult& r) {
  const size_t plane = size_t(r.width) * r.height;
  std::vector<RgbImage> frames;
  for (int64_t j = 0; j < r.rendered; ++j) {
    RgbImage view{r.width, r.height, std::vector<uint8_t>(plane * 3)};
    const float* p = r.rgb.data() + size_t(j) * 3 * plane;
    for (size_t i = 0; i < plane; ++i)
      for (int c = 0; c < 3; ++c) view.pixels[i * 3 + c] = toUint8(p[c * plane + i]);
    if (size_t(j) < r.labelMaps.size()) {
      const RgbImage labels = labelImage(r.labelMaps[size_t(j)], r.labelHeight, r.labelWidth, r.labels, r.height,
                                         r.width);
      frames.push_back(besideEachOther({&view, &labels}));
    } else {
      frames.push_back(std::move(view));
    }
  }
  return frames;
}

}  // namespace spar::cli
