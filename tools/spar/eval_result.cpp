#include "tools/spar/eval_result.h"

#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>

#include "spar/error.h"
#include "tools/spar/index_page.h"
#include "tools/spar/render_outputs.h"
#include "tools/spar/staged_dir.h"

namespace spar::cli::eval {
namespace {

using ojson = nlohmann::ordered_json;
using json = nlohmann::json;

ojson orNull(std::optional<double> v) { return v && std::isfinite(*v) ? ojson(*v) : ojson(nullptr); }

std::string cell(std::optional<double> v, const char* format) {
  if (!v || !std::isfinite(*v)) return "-";
  char buf[32];
  std::snprintf(buf, sizeof(buf), format, *v);
  return buf;
}

template <typename T>
T field(const json& doc, const char* key, const std::string& where) {
  if (!doc.contains(key)) throw Error(where + ": no \"" + std::string(key) + "\" (not a result of this spar eval)");
  try {
    return doc[key].get<T>();
  } catch (const json::exception&) {
    throw Error(where + ": \"" + std::string(key) + "\" has the wrong type");
  }
}

template <typename T>
std::string text(const T& v) {
  return ojson(v).dump();
}

// The set at each K, pooled from the tallies in scene order.
std::map<int, KTotals> totals(const EvalRun& run, const Tallies& tallies) {
  std::map<int, KTotals> out;
  for (int k : run.views) {
    std::vector<const SceneTally*> list;
    for (const auto& [scene, byK] : tallies) list.push_back(&byK.at(k));
    out[k] = pool(list, run.semantic ? int(run.classNames.size()) : 0);
  }
  return out;
}

}  // namespace

std::string modelDigest(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("cannot read " + path);
  // 64-bit words, each multiplied into the state and mixed (splitmix64's constants); the
  // length last, so files that differ only by trailing zero bytes differ.
  uint64_t h = 0x243F6A8885A308D3ull, length = 0;
  constexpr size_t kChunk = size_t(1) << 20;
  std::vector<char> buf(kChunk + 8);
  while (in) {
    in.read(buf.data(), std::streamsize(kChunk));
    const size_t n = size_t(in.gcount());
    if (n == 0) break;
    length += n;
    std::memset(buf.data() + n, 0, 8);  // a last partial word reads zeros
    for (size_t i = 0; i < n; i += 8) {
      uint64_t w = 0;
      std::memcpy(&w, buf.data() + i, 8);
      h ^= w * 0x9E3779B97F4A7C15ull;
      h = ((h << 31) | (h >> 33)) * 0xBF58476D1CE4E5B9ull;
    }
  }
  if (in.bad()) throw Error("cannot read " + path);
  h ^= length;
  h ^= h >> 30, h *= 0xBF58476D1CE4E5B9ull, h ^= h >> 27, h *= 0x94D049BB133111EBull, h ^= h >> 31;
  char hex[17];
  std::snprintf(hex, sizeof(hex), "%016llx", static_cast<unsigned long long>(h));
  return hex;
}

ojson runJson(const EvalRun& r) {
  ojson j = {{"model", r.model},     {"scenes_dir", r.scenesDir},     {"model_digest", r.modelDigest}, {"model_bytes", r.modelBytes},
             {"runner", "engine"},   {"precision", r.precision},      {"mode", r.mode},
             {"refine", r.refine},   {"semantic", r.semantic},        {"frames", r.frames},
             {"views", r.views},     {"size", {r.height, r.width}},   {"classes", r.classNames},
             {"set_scenes", r.setScenes}};
  if (r.shards > 1) j["shard"] = {{"index", r.shard}, {"count", r.shards}};
  return j;
}

EvalRun runFromJson(const json& doc, const std::string& where) {
  if (!doc.is_object() || doc.value("format", "") != "spar-eval") throw Error(where + " is not a spar eval result");
  EvalRun r;
  r.model = field<std::string>(doc, "model", where);
  r.scenesDir = doc.value("scenes_dir", "");
  r.modelDigest = field<std::string>(doc, "model_digest", where);
  r.modelBytes = field<uint64_t>(doc, "model_bytes", where);
  if (field<std::string>(doc, "runner", where) != "engine") throw Error(where + ": not the engine's result");
  r.precision = field<std::string>(doc, "precision", where);
  r.mode = field<std::string>(doc, "mode", where);
  r.refine = field<bool>(doc, "refine", where);
  r.semantic = field<bool>(doc, "semantic", where);
  r.frames = field<int>(doc, "frames", where);
  r.views = field<std::vector<int>>(doc, "views", where);
  const auto size = field<std::vector<int>>(doc, "size", where);
  if (size.size() != 2) throw Error(where + ": \"size\" is not [height, width]");
  r.height = size[0], r.width = size[1];
  r.classNames = field<std::vector<std::string>>(doc, "classes", where);
  r.setScenes = field<int>(doc, "set_scenes", where);
  if (doc.contains("shard")) {
    r.shard = field<int>(doc["shard"], "index", where);
    r.shards = field<int>(doc["shard"], "count", where);
  }
  if (r.views.empty() || r.setScenes < 1 || r.shards < 1 || r.shard < 0 || r.shard >= r.shards)
    throw Error(where + ": an impossible run description");
  return r;
}

std::string runDifference(const EvalRun& a, const EvalRun& b) {
  auto differs = [](const char* what, const std::string& x, const std::string& y) {
    return x == y ? std::string() : std::string(what) + ": " + x + " and " + y;
  };
  for (const std::string& d :
       {differs("model (its bytes)", a.modelDigest + " (" + std::to_string(a.modelBytes) + " bytes)",
                b.modelDigest + " (" + std::to_string(b.modelBytes) + " bytes)"),
        differs("precision", a.precision, b.precision), differs("mode", a.mode, b.mode),
        differs("refine", text(a.refine), text(b.refine)), differs("views", text(a.views), text(b.views)),
        differs("size", std::to_string(a.height) + "x" + std::to_string(a.width),
                std::to_string(b.height) + "x" + std::to_string(b.width)),
        differs("frames", std::to_string(a.frames), std::to_string(b.frames)),
        differs("classes", text(a.classNames), text(b.classNames)),
        differs("scenes in the set", std::to_string(a.setScenes), std::to_string(b.setScenes)),
        differs("shard count", std::to_string(a.shards), std::to_string(b.shards))})
    if (!d.empty()) return d;
  return "";
}

ojson resultDocument(const EvalRun& run, const Tallies& tallies) {
  ojson byK = ojson::object();
  const bool masks = run.masks();
  for (const auto& [k, t] : totals(run, tallies)) {
    const SceneTally& s = t.sum;
    byK[std::to_string(k)] = {
        {"psnr", orNull(t.psnr())},
        {"ssim", orNull(t.ssim())},
        {"psnr_nearest_input", orNull(t.copyPsnr())},
        {"ssim_nearest_input", orNull(t.copySsim())},
        {"psnr_mean_colour", orNull(t.meanPsnr())},
        {"mask_miou", masks ? orNull(s.masks.meanIou()) : ojson(nullptr)},
        {"mask_iou_dynamic", masks ? orNull(s.masks.iouDynamic()) : ojson(nullptr)},
        {"mask_recall", masks ? orNull(s.masks.recall()) : ojson(nullptr)},
        {"refined_mask_miou", run.refine ? orNull(s.refinedMasks.meanIou()) : ojson(nullptr)},
        {"refined_mask_iou_dynamic", run.refine ? orNull(s.refinedMasks.iouDynamic()) : ojson(nullptr)},
        {"refined_mask_recall", run.refine ? orNull(s.refinedMasks.recall()) : ojson(nullptr)},
        {"sem_miou", s.semantic ? orNull(s.semantic->meanIou()) : ojson(nullptr)},
        {"sem_accuracy", s.semantic ? orNull(s.semantic->accuracy()) : ojson(nullptr)},
        {"target_views", s.targetViews},
        {"seconds", s.seconds},
        {"ms_per_scene", orNull(median(t.sceneMs))},
    };
  }
  ojson doc = {{"format", "spar-eval"}, {"version", 1}};
  doc.update(runJson(run));
  doc["scenes"] = tallies.size();
  doc["results"] = byK;
  doc["scene_names"] = ojson::array();
  ojson perScene = ojson::object();
  for (const auto& [scene, byScene] : tallies) {
    doc["scene_names"].push_back(scene);
    for (const auto& [k, t] : byScene) perScene[scene][std::to_string(k)] = toJson(t);
  }
  doc["tallies"] = perScene;
  return doc;
}

Tallies talliesFromJson(const json& doc, const EvalRun& run, const std::string& where) {
  const auto names = field<std::vector<std::string>>(doc, "scene_names", where);
  if (!doc.contains("tallies") || !doc["tallies"].is_object()) throw Error(where + ": no per-scene tallies");
  const int classes = run.semantic ? int(run.classNames.size()) : 0;
  Tallies out;
  for (const std::string& scene : names) {
    if (!doc["tallies"].contains(scene)) throw Error(where + ": no tallies of " + scene);
    const json& byK = doc["tallies"][scene];
    for (int k : run.views) {
      const std::string key = std::to_string(k);
      if (!byK.contains(key)) throw Error(where + ": no tally of " + scene + " at K=" + key);
      out[scene][k] = tallyFromJson(byK[key], classes, where + ": " + scene + " K=" + key);
    }
  }
  if (out.size() != names.size()) throw Error(where + ": a scene is named twice");
  return out;
}

std::string checkResultPath(const std::string& out) {
  namespace fs = std::filesystem;
  const fs::path path = fs::absolute(out);
  std::error_code ec;
  if (!fs::is_directory(path.parent_path(), ec))
    throw Error("the parent directory of --out does not exist: " + path.parent_path().string());
  if (fs::is_directory(path, ec)) throw Error("--out is a directory: " + out);
  checkWritable(path.parent_path().string(), path.string());
  return path.string();
}

void writeResult(const std::string& path, const ojson& doc, const std::string& device,
                 const std::vector<std::string>& warnings) {
  writeJson(path, doc);
  std::filesystem::path page = path;
  page.replace_extension(".html");
  if (page != path) {
    std::ofstream html(page, std::ios::binary);
    html << evalResultsPage(doc, device, warnings);
  }
}

void printTable(const EvalRun& run, const Tallies& tallies, const std::string& device) {
  std::printf("spar eval: %zu scenes of %d frames at %dx%d (HxW), %s, %s, %s on %s\n", tallies.size(), run.frames,
              run.height, run.width, run.mode.c_str(), run.precision.c_str(), run.model.c_str(), device.c_str());
  // copy / mean: PSNR of the baselines on the same pixels (nearest input copied, mean colour)
  std::printf("%3s %7s %8s %7s %7s %7s %9s %8s %7s %8s %7s %8s %9s\n", "K", "targets", "PSNR", "copy", "mean", "SSIM",
              "mask mIoU", "IoU dyn", "recall", "sem mIoU", "sem acc", "seconds", "ms/scene");
  const bool masks = run.masks();
  for (const auto& [k, t] : totals(run, tallies)) {
    const SceneTally& s = t.sum;
    std::printf("%3d %7lld %8s %7s %7s %7s %9s %8s %7s %8s %7s %8.2f %9s\n", k, (long long)s.targetViews,
                cell(t.psnr(), "%.2f").c_str(), cell(t.copyPsnr(), "%.2f").c_str(), cell(t.meanPsnr(), "%.2f").c_str(),
                cell(t.ssim(), "%.4f").c_str(), cell(masks ? s.masks.meanIou() : std::nullopt, "%.4f").c_str(),
                cell(masks ? s.masks.iouDynamic() : std::nullopt, "%.4f").c_str(),
                cell(masks ? s.masks.recall() : std::nullopt, "%.4f").c_str(),
                cell(s.semantic ? s.semantic->meanIou() : std::nullopt, "%.4f").c_str(),
                cell(s.semantic ? s.semantic->accuracy() : std::nullopt, "%.4f").c_str(), s.seconds,
                cell(median(t.sceneMs), "%.0f").c_str());
    if (run.refine)  // the paper's second row: the same frames' masks after SAM2.1
      std::printf("    refined (SAM2.1): mask mIoU %s, IoU dyn %s, recall %s\n",
                  cell(s.refinedMasks.meanIou(), "%.4f").c_str(), cell(s.refinedMasks.iouDynamic(), "%.4f").c_str(),
                  cell(s.refinedMasks.recall(), "%.4f").c_str());
  }
}

}  // namespace spar::cli::eval
