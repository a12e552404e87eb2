#include "tools/spar/eval_scenes.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>

#include "spar/error.h"
#include "imaging/image_prep.h"

namespace spar::cli::eval {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

json readJson(const fs::path& path) {
  std::ifstream f(path);
  if (!f) throw Error("cannot read " + path.string());
  try {
    return json::parse(f);
  } catch (const std::exception& e) {
    throw Error("cannot parse " + path.string() + ": " + e.what());
  }
}

int positiveInt(const json& doc, const char* key, const fs::path& where) {
  if (!doc.is_object() || !doc.contains(key) || !doc.at(key).is_number_integer() || doc.at(key).get<int64_t>() < 1)
    throw Error(where.string() + ": '" + key + "' must be a positive integer");
  return doc.at(key).get<int>();
}

std::string frameFile(const SceneInfo& s, const char* kind, int i) {
  char name[64];
  std::snprintf(name, sizeof(name), "%s_%02d.png", kind, i);
  return (fs::path(s.dir) / name).string();
}

void checkSize(const RgbImage& img, const SceneInfo& s, const std::string& file) {
  if (img.width != s.width || img.height != s.height)
    throw Error(file + " is " + std::to_string(img.width) + "x" + std::to_string(img.height) + ", scene.json says " +
                std::to_string(s.width) + "x" + std::to_string(s.height));
}

}  // namespace

std::vector<SceneInfo> discoverScenes(const std::string& dir, int maxScenes) {
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) throw Error("scenes directory not found: " + dir);
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir, ec)) {
    const std::string n = e.path().filename().string();
    if (n.rfind("scene_", 0) == 0 && e.is_directory()) names.push_back(n);
  }
  if (ec) throw Error("cannot list " + dir + ": " + ec.message());
  if (names.empty()) throw Error("no scene_* folders in " + dir);
  std::sort(names.begin(), names.end());  // std::string compares bytewise
  if (maxScenes > 0 && int(names.size()) > maxScenes) names.resize(size_t(maxScenes));

  std::vector<SceneInfo> scenes;
  for (const auto& n : names) {
    SceneInfo s;
    s.dir = (fs::path(dir) / n).string();
    s.name = n;
    const fs::path sceneJson = fs::path(s.dir) / "scene.json";
    const json doc = readJson(sceneJson);
    s.frames = positiveInt(doc, "n_frames", sceneJson);
    s.width = positiveInt(doc, "width", sceneJson);
    s.height = positiveInt(doc, "height", sceneJson);
    const fs::path classesJson = fs::path(s.dir) / "classes.json";
    const json classes = readJson(classesJson);
    if (!classes.is_array() || classes.empty()) throw Error(classesJson.string() + ": expected a list of classes");
    for (size_t i = 0; i < classes.size(); ++i) {
      const json& c = classes[i];
      // Ids in order 0..C-1: the prompts' order is the label index, which must be the class id.
      if (!c.is_object() || !c.contains("id") || !c.at("id").is_number_integer() || c.at("id").get<int64_t>() != int64_t(i) ||
          !c.contains("name") || !c.at("name").is_string())
        throw Error(classesJson.string() + ": entry " + std::to_string(i) + " must be {\"id\": " + std::to_string(i) +
                    ", \"name\": ...}");
      s.classNames.push_back(c.at("name").get<std::string>());
    }
    scenes.push_back(std::move(s));
  }
  return scenes;
}

SceneData loadScene(const SceneInfo& s) {
  // Class colours -> ids, from classes.json (the palette the class maps were written with).
  const fs::path classesJson = fs::path(s.dir) / "classes.json";
  const json classes = readJson(classesJson);
  std::map<uint32_t, int32_t> colourToId;
  for (size_t i = 0; i < classes.size(); ++i) {
    const json& col = classes[i].value("color", json());
    if (!col.is_array() || col.size() != 3) throw Error(classesJson.string() + ": entry " + std::to_string(i) + " has no color");
    const uint32_t key = (col[0].get<uint32_t>() << 16) | (col[1].get<uint32_t>() << 8) | col[2].get<uint32_t>();
    if (!colourToId.emplace(key, int32_t(i)).second)
      throw Error(classesJson.string() + ": two classes share the colour of entry " + std::to_string(i));
  }

  SceneData d;
  const size_t plane = size_t(s.width) * s.height;
  d.dynamic.resize(size_t(s.frames) * plane);
  d.classes.resize(size_t(s.frames) * plane);
  for (int i = 0; i < s.frames; ++i) {
    const std::string rgbFile = frameFile(s, "rgb", i), maskFile = frameFile(s, "mask", i),
                      classFile = frameFile(s, "class", i);
    const RgbImage rgb = loadImageRGB(rgbFile);
    checkSize(rgb, s, rgbFile);
    const std::vector<float> chw = prepareImage(rgb, s.height, s.width);  // same size: exactly value / 255
    d.rgb.insert(d.rgb.end(), chw.begin(), chw.end());

    const RgbImage mask = loadImageRGB(maskFile);  // grey, replicated into RGB
    checkSize(mask, s, maskFile);
    for (size_t p = 0; p < plane; ++p) d.dynamic[size_t(i) * plane + p] = mask.pixels[p * 3] > 127 ? 1 : 0;

    const RgbImage cls = loadImageRGB(classFile);
    checkSize(cls, s, classFile);
    for (size_t p = 0; p < plane; ++p) {
      const uint8_t* px = &cls.pixels[p * 3];
      const auto it = colourToId.find((uint32_t(px[0]) << 16) | (uint32_t(px[1]) << 8) | px[2]);
      if (it == colourToId.end())
        throw Error(classFile + ": pixel " + std::to_string(p) + " has a colour of no class in classes.json");
      d.classes[size_t(i) * plane + p] = it->second;
    }
  }
  return d;
}

std::vector<int64_t> inputPositions(int frames, int views) {
  if (views < 2 || views > frames)
    throw Error("cannot take " + std::to_string(views) + " input views of " + std::to_string(frames) + " frames");
  // floor(j (F-1) / (K-1) + 1/2) = floor((2 j (F-1) + (K-1)) / (2 (K-1)))
  std::vector<int64_t> out;
  for (int64_t j = 0; j < views; ++j) out.push_back((2 * j * (frames - 1) + (views - 1)) / (2 * (views - 1)));
  return out;
}

}  // namespace spar::cli::eval
