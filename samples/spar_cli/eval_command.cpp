#include "samples/spar_cli/eval_command.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <optional>

#include "engine/engine.h"
#include "formats/cameras.h"
#include "model/packed_model.h"
#include "model/spar_config.h"
#include "model/spar_pipeline.h"
#include "samples/spar_cli/errors.h"
#include "samples/spar_cli/staged_dir.h"
#include "samples/spar_cli/eval_metrics.h"
#include "samples/spar_cli/eval_scenes.h"
#include "text/prompt_labels.h"
#include "samples/spar_cli/warnings.h"
#include "samples/spar_cli/index_page.h"
#include "samples/spar_cli/progress.h"
#include "samples/spar_cli/render_outputs.h"
#include "model/weight_set.h"

namespace spar::cli {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using namespace spar::cli::eval;
using ojson = nlohmann::ordered_json;

// PROTOCOL.md: predicted dynamic = P(dynamic) > 0.5.
constexpr float kMaskThreshold = 0.5f;

double msSince(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }

// "2, 3,4" -> {2, 3, 4} (increasing, no repeats); only the syntax is judged here.
std::vector<int> parseViews(const std::string& text) {
  std::vector<int> out;
  std::string item;
  auto flush = [&]() {
    if (item.empty()) throw UsageError("--views must be comma-separated numbers of input views, got '" + text + "'");
    size_t used = 0;
    int v = 0;
    try {
      v = std::stoi(item, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used != item.size()) throw UsageError("--views must be comma-separated numbers of input views, got '" + text + "'");
    for (int seen : out)
      if (seen == v) throw UsageError("--views repeats " + item);
    out.push_back(v);
    item.clear();
  };
  for (char ch : text) {
    if (ch == ',') flush();
    else if (ch != ' ') item += ch;
  }
  flush();
  std::sort(out.begin(), out.end());
  return out;
}

// Accumulators of one K over all scenes.
struct KResult {
  int k = 0;
  std::vector<int64_t> inputs, targets;
  double psnrSum = 0, ssimSum = 0;
  int64_t psnrViews = 0, ssimViews = 0, targetViews = 0;
  // PROTOCOL.md "Baselines": the nearest input copied, the inputs' mean colour (same views)
  double copyPsnrSum = 0, copySsimSum = 0, meanPsnrSum = 0;
  MaskCounts masks, refinedMasks;  // CV-DRP's, SAM2.1's (--refine)
  std::unique_ptr<SemanticConfusion> semantic;
  double seconds = 0;
  std::vector<double> sceneMs;
  // Means over the evaluated target views of all scenes.
  std::optional<double> psnr() const { return psnrViews ? std::optional<double>(psnrSum / double(psnrViews)) : std::nullopt; }
  std::optional<double> ssim() const { return ssimViews ? std::optional<double>(ssimSum / double(ssimViews)) : std::nullopt; }
  // The baselines skip exactly the views the model's metrics skip (no static pixel / centre).
  std::optional<double> copyPsnr() const { return psnrViews ? std::optional<double>(copyPsnrSum / double(psnrViews)) : std::nullopt; }
  std::optional<double> copySsim() const { return ssimViews ? std::optional<double>(copySsimSum / double(ssimViews)) : std::nullopt; }
  std::optional<double> meanPsnr() const { return psnrViews ? std::optional<double>(meanPsnrSum / double(psnrViews)) : std::nullopt; }
};

ojson orNull(std::optional<double> v) { return v && std::isfinite(*v) ? ojson(*v) : ojson(nullptr); }

std::string cell(std::optional<double> v, const char* format) {
  if (!v || !std::isfinite(*v)) return "-";
  char buf[32];
  std::snprintf(buf, sizeof(buf), format, *v);
  return buf;
}

}  // namespace

void runEval(const EvalArgs& a) {
  takeWarnings();  // the results page lists this evaluation's warnings only
  const auto start = Clock::now();
  // 1. The command line alone (exit 2).
  if (a.noGating && a.assumeStatic) throw UsageError("--no-gating and --assume-static exclude each other");
  try {
    WeightSet::precisionType(a.precision);
  } catch (const Error& e) {
    throw UsageError(e.what());
  }
  if (a.maskSource != "raw" && a.maskSource != "refined") throw UsageError("--mask-source must be raw or refined");
  const bool refine = a.refine || a.maskSource == "refined";
  if (refine && a.assumeStatic) throw UsageError("--refine / --mask-source refined and --assume-static exclude each other");
  if (a.maxScenes < 0) throw UsageError("--max-scenes must be at least 1");  // 0: all scenes
  const std::vector<int> ks = parseViews(a.views);
  const std::string mode = a.assumeStatic            ? "assume-static"
                           : a.noGating               ? "no-gating"
                           : a.maskSource == "refined" ? "refined-gating"
                                                       : "default";

  // 2. Files (exit 1), cheapest first: nothing heavy is loaded before everything named exists.
  if (!fs::exists(a.model)) throw Error("model not found: " + a.model);
  const fs::path outPath = fs::absolute(a.out);
  std::error_code ec;
  if (!fs::is_directory(outPath.parent_path(), ec))
    throw Error("the parent directory of --out does not exist: " + outPath.parent_path().string());
  if (fs::is_directory(outPath, ec)) throw Error("--out is a directory: " + a.out);
  checkWritable(outPath.parent_path().string(), outPath.string());
  // --shard I/N: the scenes whose position (after --max-scenes) is I modulo N, so N processes
  // (a batch system's job array) together evaluate every scene once.
  const std::vector<SceneInfo> scenes = [&] {
    std::vector<SceneInfo> all = discoverScenes(a.scenes, a.maxScenes), mine;
    for (size_t k = 0; k < all.size(); ++k)
      if (int(k % size_t(a.shards)) == a.shard) mine.push_back(std::move(all[k]));
    if (mine.empty())
      throw Error("shard " + std::to_string(a.shard) + "/" + std::to_string(a.shards) + " has no scenes (" +
                  std::to_string(all.size()) + " in " + a.scenes + ")");
    return mine;
  }();
  const int frames = scenes.front().frames;
  for (const auto& s : scenes) {
    if (s.frames != frames)
      throw Error(s.name + " has " + std::to_string(s.frames) + " frames, " + scenes.front().name + " has " +
                  std::to_string(frames) + " (one F per test set)");
    // One set of prompts for the run: text embeddings are computed once.
    if (s.classNames != scenes.front().classNames)
      throw Error(s.name + "/classes.json differs from " + scenes.front().name + "/classes.json");
  }
  for (int k : ks)
    if (k < 2 || k >= frames)
      throw UsageError("--views " + std::to_string(k) + ": need 2 .. " + std::to_string(frames - 1) +
                       " input views (at least one of the " + std::to_string(frames) + " frames must be a target)");

  const PackedModel model = PackedModel::open(a.model);
  const SparConfig cfg = SparConfig::fromJson(model.config(), model.path());
  if (const std::string problem = refine ? refinementProblem(model) : ""; !problem.empty())
    throw Error(problem + ": --refine / --mask-source refined are not available");
  // --size: a size this model cannot run at is a command line without meaning for it (exit 2).
  if (a.height) {
    if (const std::string problem = imageSizeProblem(cfg, a.height, a.width); !problem.empty())
      throw UsageError("--size: " + problem);
  }
  const int h = int(a.height ? a.height : cfg.imageHeight), w = int(a.width ? a.width : cfg.imageWidth);
  const std::string sizeText = std::to_string(h) + "x" + std::to_string(w) + " (HxW)";
  for (const auto& s : scenes)
    if (s.width != w || s.height != h)
      throw Error(s.name + " is " + std::to_string(s.height) + "x" + std::to_string(s.width) + " (HxW), the size " +
                  (a.height ? "--size gives" : "of the model") + " is " + sizeText + " (evaluation does not resize)");
  // Semantic metrics only for models that decode semantics; those need the CLIP tokenizer.
  const bool semantic = cfg.semanticDecoding();
  const std::vector<std::string>& classNames = scenes.front().classNames;
  std::vector<int32_t> promptIds;
  if (semantic) {
    const TokenizedPrompts tokenized = tokenizePrompts(model, classNames);
    warnAboutPrompts(tokenized, classNames.size());
    promptIds = tokenized.ids;
  }

  const size_t plane = size_t(h) * size_t(w);
  std::vector<KResult> results(ks.size());
  for (size_t i = 0; i < ks.size(); ++i) {
    KResult& r = results[i];
    r.k = ks[i];
    r.inputs = inputPositions(frames, r.k);
    for (int64_t f = 0; f < frames; ++f)
      if (std::find(r.inputs.begin(), r.inputs.end(), f) == r.inputs.end()) r.targets.push_back(f);
    if (semantic) r.semantic = std::make_unique<SemanticConfusion>(int(classNames.size()));
  }

  Progress progress;
  std::string deviceName;
  try {
    progress.step("opening the Vulkan device");
    EngineOptions eo;
    eo.device = a.device;
    eo.pipelineCacheFile = pipelineCachePath();
    eo = EngineOptions::fromEnvironment(eo);
    Engine engine(eo);
    deviceName = engine.caps().name;
    SparPipelineOptions po;
    po.profile = false;
    po.weightType = WeightSet::precisionType(a.precision);
    SparPipeline pipeline(engine, model, po);  // once: weights stay on the device for every scene
    PromptEmbeddings text;
    if (semantic) {
      progress.step("encoding " + std::to_string(classNames.size()) + " class names");
      text = encodePrompts(engine, model, cfg, po.weightType, promptIds, int64_t(classNames.size()));
    }

    // Scenes outer, K inner: each scene is read once.
    for (size_t si = 0; si < scenes.size(); ++si) {
      const SceneInfo& scene = scenes[si];
      const SceneData data = loadScene(scene);
      for (KResult& r : results) {
        progress.step("scene " + std::to_string(si + 1) + "/" + std::to_string(scenes.size()) + " " + scene.name +
                      ", K=" + std::to_string(r.k) + " (" + mode + ")");
        // Wall time of the model's work on this scene: encode, render, label maps on the host.
        const auto t = Clock::now();
        SparRequest req;
        req.images = data.rgb;
        req.height = h;
        req.width = w;
        req.plan.views = frames;
        req.plan.inputs = r.inputs;
        req.plan.targets = r.targets;
        req.assumeStatic = a.assumeStatic;
        req.targetMotion = !a.assumeStatic;
        req.gating = !a.noGating;
        req.semanticFeatures = semantic;
        req.refine = refine;
        req.maskSource = a.maskSource == "refined" ? MaskSource::Refined : MaskSource::Raw;
        const SparEncoded& enc = pipeline.encode(req);
        const std::vector<float> rgb = pipeline.renderTargets();
        std::vector<std::vector<int32_t>> labels;
        if (semantic) labels = computeLabelMaps(engine, pipeline.renderedFeatures(), text).maps;
        const double ms = msSince(t);
        r.sceneMs.push_back(ms);

        const std::vector<float> meanColour = meanColourImage(data.rgb, r.inputs, h, w);
        for (size_t j = 0; j < r.targets.size(); ++j) {
          const size_t f = size_t(r.targets[j]);
          const float* gt = &data.rgb[f * 3 * plane];
          const uint8_t* dyn = &data.dynamic[f * plane];
          const float* copy = &data.rgb[size_t(nearestInput(r.targets[j], r.inputs)) * 3 * plane];
          ++r.targetViews;
          if (const auto p = staticPsnr(&rgb[j * 3 * plane], gt, dyn, h, w)) {
            r.psnrSum += *p, ++r.psnrViews;
            r.copyPsnrSum += *staticPsnr(copy, gt, dyn, h, w);
            r.meanPsnrSum += *staticPsnr(meanColour.data(), gt, dyn, h, w);
          }
          if (const auto s = staticSsim(&rgb[j * 3 * plane], gt, dyn, h, w)) {
            r.ssimSum += *s, ++r.ssimViews;
            r.copySsimSum += *staticSsim(copy, gt, dyn, h, w);
          }
          if (semantic) r.semantic->add(labels[j].data(), &data.classes[f * plane], dyn, h, w);
        }
        if (!a.assumeStatic) {
          for (size_t j = 0; j < r.inputs.size(); ++j)
            r.masks.add(&enc.motionInput[j * plane], &data.dynamic[size_t(r.inputs[j]) * plane], plane, kMaskThreshold);
          for (size_t j = 0; j < r.targets.size(); ++j)
            r.masks.add(&enc.motionTarget[j * plane], &data.dynamic[size_t(r.targets[j]) * plane], plane,
                        kMaskThreshold);
        }
        if (refine) {  // the refined masks hold 0 or 1: the same threshold reads them
          for (size_t j = 0; j < r.inputs.size(); ++j)
            r.refinedMasks.add(&enc.refinedInput[j * plane], &data.dynamic[size_t(r.inputs[j]) * plane], plane,
                               kMaskThreshold);
          for (size_t j = 0; j < r.targets.size(); ++j)
            r.refinedMasks.add(&enc.refinedTarget[j * plane], &data.dynamic[size_t(r.targets[j]) * plane], plane,
                               kMaskThreshold);
        }
        r.seconds += msSince(t) / 1000.0;
      }
    }
    progress.finish();
  } catch (...) {
    progress.finish();
    throw;
  }

  // result.json (PROTOCOL.md, "Output JSON").
  ojson byK = ojson::object();
  for (const KResult& r : results) {
    const bool masks = !a.assumeStatic;
    byK[std::to_string(r.k)] = {
        {"psnr", orNull(r.psnr())},
        {"ssim", orNull(r.ssim())},
        {"psnr_nearest_input", orNull(r.copyPsnr())},
        {"ssim_nearest_input", orNull(r.copySsim())},
        {"psnr_mean_colour", orNull(r.meanPsnr())},
        {"mask_miou", masks ? orNull(r.masks.meanIou()) : ojson(nullptr)},
        {"mask_iou_dynamic", masks ? orNull(r.masks.iouDynamic()) : ojson(nullptr)},
        {"mask_recall", masks ? orNull(r.masks.recall()) : ojson(nullptr)},
        {"refined_mask_miou", refine ? orNull(r.refinedMasks.meanIou()) : ojson(nullptr)},
        {"refined_mask_iou_dynamic", refine ? orNull(r.refinedMasks.iouDynamic()) : ojson(nullptr)},
        {"refined_mask_recall", refine ? orNull(r.refinedMasks.recall()) : ojson(nullptr)},
        {"sem_miou", r.semantic ? orNull(r.semantic->meanIou()) : ojson(nullptr)},
        {"sem_accuracy", r.semantic ? orNull(r.semantic->accuracy()) : ojson(nullptr)},
        {"target_views", r.targetViews},
        {"seconds", r.seconds},
        {"ms_per_scene", orNull(median(r.sceneMs))},
    };
  }
  ojson doc = {{"format", "spar-eval"},
                     {"version", 1},
                     {"model", absolutePath(a.model)},
                     {"runner", "engine"},
                     {"precision", a.precision},
                     {"mode", mode},
                     {"refine", refine},
                     {"scenes", scenes.size()},
                     {"frames", frames},
                     {"results", byK}};
  if (a.shards > 1) {
    // Which part of the test set this is, and its scenes, for combining shards (docs/many-scenes.md).
    doc["shard"] = {{"index", a.shard}, {"count", a.shards}};
    doc["scene_names"] = ojson::array();
    for (const auto& s : scenes) doc["scene_names"].push_back(s.name);
  }
  writeJson(outPath.string(), doc);
  // Beside it, the same as a page (result.json -> result.html): a table to look at.
  {
    fs::path page = outPath;
    page.replace_extension(".html");
    if (page != outPath) {
      std::ofstream html(page, std::ios::binary);
      html << evalResultsPage(doc, deviceName, takeWarnings());
    }
  }

  // The table on stdout.
  std::printf("spar eval: %zu scenes of %d frames at %s, %s, %s, %s on %s\n", scenes.size(), frames,
              sizeText.c_str(), mode.c_str(), a.precision.c_str(), a.model.c_str(), deviceName.c_str());
  // copy / mean: PSNR of the baselines on the same pixels (nearest input copied, mean colour)
  std::printf("%3s %7s %8s %7s %7s %7s %9s %8s %7s %8s %7s %8s %9s\n", "K", "targets", "PSNR", "copy", "mean", "SSIM",
              "mask mIoU", "IoU dyn", "recall", "sem mIoU", "sem acc", "seconds", "ms/scene");
  for (const KResult& r : results) {
    const bool masks = !a.assumeStatic;
    std::printf("%3d %7lld %8s %7s %7s %7s %9s %8s %7s %8s %7s %8.2f %9s\n", r.k, (long long)r.targetViews,
                cell(r.psnr(), "%.2f").c_str(), cell(r.copyPsnr(), "%.2f").c_str(), cell(r.meanPsnr(), "%.2f").c_str(),
                cell(r.ssim(), "%.4f").c_str(),
                cell(masks ? r.masks.meanIou() : std::nullopt, "%.4f").c_str(),
                cell(masks ? r.masks.iouDynamic() : std::nullopt, "%.4f").c_str(),
                cell(masks ? r.masks.recall() : std::nullopt, "%.4f").c_str(),
                cell(r.semantic ? r.semantic->meanIou() : std::nullopt, "%.4f").c_str(),
                cell(r.semantic ? r.semantic->accuracy() : std::nullopt, "%.4f").c_str(), r.seconds,
                cell(median(r.sceneMs), "%.0f").c_str());
    if (refine)  // the paper's second row: the same frames' masks after SAM2.1
      std::printf("    refined (SAM2.1): mask mIoU %s, IoU dyn %s, recall %s\n",
                  cell(r.refinedMasks.meanIou(), "%.4f").c_str(), cell(r.refinedMasks.iouDynamic(), "%.4f").c_str(),
                  cell(r.refinedMasks.recall(), "%.4f").c_str());
  }
  std::printf("wrote %s in %.1f s\n", outPath.string().c_str(), msSince(start) / 1000.0);
}

}  // namespace spar::cli
