#include "tools/spar/render_outputs.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <cstring>
#include <fstream>

#include "spar/error.h"
#include "formats/colmap.h"
#include "imaging/float_image.h"
#include "imaging/image_prep.h"
#include "imaging/label_outputs.h"
#include "formats/npy.h"

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

RgbImage besideEachOther(const std::vector<const RgbImage*>& parts) {
  RgbImage out;
  for (const RgbImage* p : parts) {
    out.width += p->width;
    out.height = std::max(out.height, p->height);
  }
  out.pixels.assign(size_t(out.width) * out.height * 3, 0);
  int x0 = 0;
  for (const RgbImage* p : parts) {
    for (int y = 0; y < p->height; ++y)
      std::memcpy(&out.pixels[(size_t(y) * out.width + x0) * 3], &p->pixels[size_t(y) * p->width * 3],
                  size_t(p->width) * 3);
    x0 += p->width;
  }
  return out;
}

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

RenderWriter::RenderWriter(std::string dir, RenderLayout layout) : dir_(std::move(dir)), layout_(std::move(layout)) {
  if (layout_.animationFps > 0) animation_ = openAnimation(layout_.animation, dir_, layout_.animationFps);
}

RenderWriter::~RenderWriter() = default;

std::string RenderWriter::animationFile() const { return animation_ ? animation_->fileName() : ""; }
std::string RenderWriter::animationDescription() const { return animation_ ? animation_->description() : ""; }

RgbImage RenderWriter::frame(const float* p, const std::vector<int32_t>* labelMap) const {
  const size_t plane = size_t(layout_.width) * layout_.height;
  RgbImage view{layout_.width, layout_.height, std::vector<uint8_t>(plane * 3)};
  for (size_t i = 0; i < plane; ++i)
    for (int c = 0; c < 3; ++c) view.pixels[i * 3 + c] = toUint8(p[c * plane + i]);
  if (!labelMap) return view;
  // label maps are at the image's size (spar::Session::labelMaps)
  const RgbImage labels = labelImage(*labelMap, layout_.height, layout_.width, layout_.labels, layout_.height,
                                     layout_.width);
  return besideEachOther({&view, &labels});
}

void RenderWriter::addViews(const RenderedViews& v) {
  const int H = layout_.height, W = layout_.width, h = H / 2, w = W / 2;
  const size_t plane = size_t(W) * H;
  const int64_t n = v.count;
  if (v.labelMaps && v.labelMaps->size() != size_t(n)) throw Error("render result: wrong number of label maps");
  const int64_t p = int64_t(layout_.labels.size());
  if (v.scores && v.scores->size() != size_t(n * p * h * w)) throw Error("render result: wrong number of score values");
  const int64_t c = layout_.featureChannels;
  if (v.features && v.features->size() != size_t(n * c * h * w))
    throw Error("render result: wrong number of feature values");
  for (int64_t i = 0; i < n; ++i) {
    const int64_t j = next_ + i;
    const float* view = v.rgb + size_t(i) * 3 * plane;
    const std::string& f = layout_.viewFormat;
    if (f == "png") {
      writePng(numbered(dir_, "view", j), view, 3, H, W);
    } else if (f == "exr" || f == "exr16") {
      writeExr(numbered(dir_, "view", j, "exr"), view, 3, H, W, f == "exr16");
    } else if (f == "npy") {
      writeNpy(numbered(dir_, "view", j, "npy"), {3, H, W}, view);
    } else {
      throw Error("unknown view format '" + f + "' (png, exr, exr16, npy)");
    }
    ++files_;
    const std::vector<int32_t>* map = v.labelMaps ? &(*v.labelMaps)[size_t(i)] : nullptr;
    if (map) {
      writeLabelPng(numbered(dir_, "labels", j), *map, H, W, layout_.labels, H, W);
      writeLabelJson(numbered(dir_, "labels", j, "json"), labelJson(*map, H, W, layout_.labels, j, lsegLogitScale()));
      files_ += 2;
    }
    if (v.scores) {
      // the official logits: at H/2 x W/2, before the x2 upsampling the label maps take
      writeNpy(numbered(dir_, "scores", j, "npy"), {p, h, w}, v.scores->data() + i * p * h * w);
      ++files_;
    }
    if (v.features) {
      writeNpy(numbered(dir_, "features", j, "npy"), {c, h, w}, v.features->data() + i * c * h * w);
      ++files_;
    }
    if (animation_) animation_->add(frame(view, map));
  }
  next_ += n;
}

void RenderWriter::writeRefined(const std::vector<float>& masks, int64_t views) {
  const size_t plane = size_t(layout_.width) * layout_.height;
  if (masks.size() != size_t(views) * plane) throw Error("render result: wrong number of refined mask values");
  for (int64_t j = 0; j < views; ++j) {
    writePng(numbered(dir_, "refined", j), masks.data() + size_t(j) * plane, 1, layout_.height, layout_.width);
    ++files_;
  }
}

void RenderWriter::finish(const std::vector<float>& motion, int64_t motionViews, float maskThreshold,
                          const CamerasDocument& cams) {
  const size_t plane = size_t(layout_.width) * layout_.height;
  if (motion.size() != size_t(motionViews) * plane) throw Error("render result: wrong number of motion values");
  std::vector<float> mask(plane);
  for (int64_t j = 0; j < motionViews; ++j) {
    const float* p = motion.data() + size_t(j) * plane;
    writePng(numbered(dir_, "motion", j), p, 1, layout_.height, layout_.width);
    // The reference's binary mask: prob > threshold, written as 0 / 255.
    for (size_t i = 0; i < plane; ++i) mask[i] = p[i] > maskThreshold ? 1.0f : 0.0f;
    writePng(numbered(dir_, "mask", j), mask.data(), 1, layout_.height, layout_.width);
    files_ += 2;
  }
  writeJson((std::filesystem::path(dir_) / "cameras.json").string(), camerasJson(cams));
  ++files_;
  files_ += writeColmapModels(dir_, cams);
  if (animation_) {
    animation_->finish();
    ++files_;
  }
}

}  // namespace spar::cli
