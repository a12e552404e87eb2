#include "imaging/label_outputs.h"

#include <algorithm>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>


#include "spar/error.h"
#include "imaging/image_files.h"
#include "model/label_maps.h"

namespace spar {
namespace {

constexpr std::array<std::array<uint8_t, 3>, 20> kPalette = {{
    {230, 25, 75}, {60, 180, 75}, {255, 225, 25}, {0, 130, 200}, {245, 130, 48},
    {145, 30, 180}, {70, 240, 240}, {240, 50, 230}, {210, 245, 60}, {250, 190, 212},
    {0, 128, 128}, {220, 190, 255}, {170, 110, 40}, {255, 250, 200}, {128, 0, 0},
    {170, 255, 195}, {128, 128, 0}, {255, 215, 180}, {0, 0, 128}, {128, 128, 128},
}};

constexpr int kLegendRow = 14;  // pixels per legend row (save_label_map's `row`)

void checkMap(const std::vector<int32_t>& map, int h, int w, size_t labels) {
  if (h <= 0 || w <= 0 || map.size() != size_t(h) * size_t(w))
    throw Error("label map: " + std::to_string(map.size()) + " values for " + std::to_string(h) + " x " +
                std::to_string(w));
  for (int32_t v : map)
    if (v < 0 || size_t(v) >= labels)
      throw Error("label map: label " + std::to_string(v) + " outside [0, " + std::to_string(labels) + ")");
}

// PIL's NEAREST resize: output pixel i samples input floor((i + 0.5) * in / out).
int nearestSource(int i, int in, int out) {
  const int s = static_cast<int>(std::floor((i + 0.5) * static_cast<double>(in) / static_cast<double>(out)));
  return std::min(std::max(s, 0), in - 1);
}

void writeFileAtomically(const std::string& path, const std::string& bytes) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream f(tmp, std::ios::binary | std::ios::trunc);
    if (!f) throw Error(path + ": cannot write");
    f << bytes;
    if (!f) throw Error(path + ": write failed");
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) throw Error(path + ": cannot rename into place: " + ec.message());
}

}  // namespace

const std::string& legendFont() {
  // DejaVu Sans from Debian's fonts-dejavu-core (scripts/setup/install-deps.sh); "" when absent.
  static const std::string font = [] {
    const char* path = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";
    return std::filesystem::exists(path) ? std::string(path) : std::string();
  }();
  return font;
}

void drawLegendNames(RgbImage& img, const std::vector<std::string>& names, int outH) {
  // Each name right of its swatch, white, with OpenImageIO's FreeType text rendering. The
  // reference draws them with PIL's built-in bitmap font, whose glyph data is not ours to copy,
  // so only the text pixels differ from its PNG. Without the font the legend has swatches only.
  if (legendFont().empty() || names.empty()) return;
  const ImageFiles& files = imageFiles();
  std::string ignored;  // a name not drawn leaves its swatch: the legend stays readable
  for (size_t k = 0; k < names.size(); ++k) {
    const int baseline = outH + 2 + kLegendRow * static_cast<int>(k) + kLegendRow - 4;
    files.drawText(img.pixels.data(), img.width, img.height, 16, baseline, names[k], 11, legendFont(), &ignored);
  }
}

std::array<uint8_t, 3> paletteColour(int64_t k) {
  const int64_t n = static_cast<int64_t>(kPalette.size());
  if (k >= 0 && k < n) return kPalette[size_t(k)];
  // Beyond the reference's 20 (which repeats them), every label still gets a colour of its own:
  // j -> j * M mod 2^24 (M odd) is a bijection of 24-bit colours, so colours of different j
  // differ; the j whose colour is black (the legend's background) or a palette colour are
  // skipped, which keeps k -> colour a function of k alone and O(palette) to compute.
  constexpr uint32_t M = 0x9E3779u | 1u, mask = 0xFFFFFFu;
  uint32_t inv = M;  // M^-1 mod 2^24 by Newton's iteration (each step doubles the correct bits)
  for (int i = 0; i < 5; ++i) inv *= 2u - M * inv;
  inv &= mask;
  std::vector<uint32_t> skipped;  // the j of the colours not to use, increasing
  auto rgb = [](std::array<uint8_t, 3> c) { return uint32_t(c[0]) << 16 | uint32_t(c[1]) << 8 | c[2]; };
  skipped.push_back(0);  // black: j = 0
  for (const auto& c : kPalette) skipped.push_back((rgb(c) * inv) & mask);
  std::sort(skipped.begin(), skipped.end());
  uint64_t j = uint64_t(k < 0 ? -k : k - n);  // negative k (never a label) also get colours
  for (uint32_t s : skipped)
    if (s <= j) ++j;
  const uint32_t c = uint32_t(j * M) & mask;
  return {uint8_t(c >> 16), uint8_t(c >> 8), uint8_t(c)};
}

RgbImage labelImage(const std::vector<int32_t>& map, int h, int w, const std::vector<std::string>& names, int outH,
                    int outW) {
  checkMap(map, h, w, names.size());
  if (outH <= 0 || outW <= 0) throw Error("label map: output size must be positive");
  RgbImage img;
  img.width = outW;
  img.height = outH + kLegendRow * static_cast<int>(names.size()) + 4;
  img.pixels.assign(size_t(img.width) * size_t(img.height) * 3, 0);
  auto put = [&img](int x, int y, const std::array<uint8_t, 3>& c) {
    if (x < 0 || y < 0 || x >= img.width || y >= img.height) return;
    std::copy(c.begin(), c.end(), img.pixels.begin() + (ptrdiff_t(y) * img.width + x) * 3);
  };
  for (int y = 0; y < outH; ++y) {
    const int sy = nearestSource(y, h, outH);
    for (int x = 0; x < outW; ++x) put(x, y, paletteColour(map[size_t(sy) * size_t(w) + size_t(nearestSource(x, w, outW))]));
  }
  // Swatches: PIL's rectangle([2, y + 1, 12, y + row - 3]) includes both corners.
  for (size_t k = 0; k < names.size(); ++k) {
    const int y = outH + 2 + kLegendRow * static_cast<int>(k);
    for (int yy = y + 1; yy <= y + kLegendRow - 3; ++yy)
      for (int xx = 2; xx <= 12; ++xx) put(xx, yy, paletteColour(int64_t(k)));
  }
  drawLegendNames(img, names, outH);
  return img;
}

void writeLabelPng(const std::string& path, const std::vector<int32_t>& map, int h, int w,
                   const std::vector<std::string>& names, int outH, int outW) {
  writePng(path, labelImage(map, h, w, names, outH, outW));
}

nlohmann::ordered_json labelJson(const std::vector<int32_t>& map, int h, int w, const std::vector<std::string>& names,
                                 int64_t view, double logitScale) {
  checkMap(map, h, w, names.size());
  std::vector<int64_t> counts(names.size(), 0);
  for (int32_t v : map) ++counts[size_t(v)];
  nlohmann::ordered_json doc;
  doc["view"] = view;
  doc["resolution"] = {h, w};
  doc["logit_scale"] = logitScale;
  nlohmann::ordered_json legend = nlohmann::ordered_json::object();
  nlohmann::ordered_json labels = nlohmann::ordered_json::array();
  for (size_t k = 0; k < names.size(); ++k) {
    const auto c = paletteColour(int64_t(k));
    char hex[8];
    std::snprintf(hex, sizeof hex, "#%02x%02x%02x", c[0], c[1], c[2]);
    legend[names[k]] = hex;
    nlohmann::ordered_json entry;
    entry["index"] = k;
    entry["label"] = names[k];
    entry["colour"] = {c[0], c[1], c[2]};
    entry["pixels"] = counts[k];
    entry["share"] = static_cast<double>(counts[k]) / static_cast<double>(map.size());
    labels.push_back(entry);
  }
  doc["legend"] = legend;
  doc["labels"] = labels;
  return doc;
}

std::string labelJsonText(const nlohmann::ordered_json& doc) {
  // Python's json.dump(indent=1): one space per level, ", " never at line ends, ": " after
  // keys, ASCII only (ensure_ascii). nlohmann's dump(1, ' ', true) has the same layout.
  return doc.dump(1, ' ', true);
}

void writeLabelJson(const std::string& path, const nlohmann::ordered_json& doc) {
  writeFileAtomically(path, labelJsonText(doc));
}

double lsegLogitScale() { return kLsegLogitScale; }

void writeLabelFiles(const std::string& dir, const std::vector<int32_t>& maps, int views, int h, int w,
                     const std::vector<std::string>& names, int outH, int outW) {
  const size_t plane = size_t(h) * size_t(w);
  if (views < 0 || maps.size() != size_t(views) * plane)
    throw Error("label maps: " + std::to_string(maps.size()) + " values for " + std::to_string(views) + " views of " +
                std::to_string(h) + " x " + std::to_string(w));
  for (int v = 0; v < views; ++v) {
    const std::vector<int32_t> map(maps.begin() + ptrdiff_t(v * plane), maps.begin() + ptrdiff_t((v + 1) * plane));
    char stem[32];
    std::snprintf(stem, sizeof stem, "/labels_%02d", v);
    writeLabelPng(dir + stem + ".png", map, h, w, names, outH, outW);
    writeLabelJson(dir + stem + ".json", labelJson(map, h, w, names, v, kLsegLogitScale));
  }
}

}  // namespace spar
