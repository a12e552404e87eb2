#include "tools/spar/eval_command.h"

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

#include "formats/cameras.h"
#include "spar/session.h"
#include "tools/common/errors.h"
#include "tools/spar/staged_dir.h"
#include "tools/spar/eval_metrics.h"
#include "tools/spar/eval_result.h"
#include "tools/spar/eval_scenes.h"
#include "tools/spar/warnings.h"
#include "tools/spar/index_page.h"
#include "tools/spar/progress.h"
#include "tools/spar/render_outputs.h"

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

// <out>.partial: the scenes an interrupted run finished, one file each (written whole), and
// run.json, the run they belong to. Removed once result.json is written.
fs::path partialDir(const fs::path& out) { return fs::path(out.string() + ".partial"); }

// The tallies a result file or an interrupted run already holds for this run's scenes; a
// result file of this very run makes the whole evaluation unnecessary (`complete`).
struct Earlier {
  Tallies tallies;
  bool complete = false;
};

Earlier earlierWork(const fs::path& out, const EvalRun& run, const std::vector<std::string>& names, bool redo) {
  Earlier e;
  const fs::path partial = partialDir(out);
  std::error_code ec;
  if (redo) {
    fs::remove_all(partial, ec);
    return e;
  }
  if (fs::is_regular_file(out, ec)) {
    try {  // a result of another run (or unreadable) is replaced, as before
      std::ifstream in(out);
      const nlohmann::json doc = nlohmann::json::parse(in);
      const EvalRun done = runFromJson(doc, out.string());
      if (runDifference(done, run).empty() && done.shard == run.shard && done.scenesDir == run.scenesDir &&
          doc.at("scene_names").get<std::vector<std::string>>() == names) {
        e.tallies = talliesFromJson(doc, done, out.string());
        e.complete = true;
        return e;
      }
    } catch (const std::exception&) {
    }
  }
  if (!fs::exists(partial, ec)) return e;
  const fs::path runFile = partial / "run.json";
  EvalRun earlier;
  try {
    std::ifstream in(runFile);
    earlier = runFromJson(nlohmann::json::parse(in), runFile.string());
  } catch (const std::exception& err) {
    throw Error(partial.string() + " is not an interrupted evaluation's (" + err.what() +
                "): remove it or pass --redo");
  }
  std::string diff = runDifference(earlier, run);
  if (diff.empty() && earlier.shard != run.shard)
    diff = "shard " + std::to_string(earlier.shard) + " and " + std::to_string(run.shard);
  if (diff.empty() && earlier.scenesDir != run.scenesDir) diff = "scenes " + earlier.scenesDir + " and " + run.scenesDir;
  if (!diff.empty())
    throw Error(partial.string() + " holds the finished scenes of another evaluation (" + diff +
                "): remove it or pass --redo");
  for (const std::string& name : names) {
    const fs::path f = partial / (name + ".json");
    if (!fs::exists(f, ec)) continue;
    std::ifstream in(f);
    nlohmann::json doc;
    try {
      doc = nlohmann::json::parse(in);
    } catch (const std::exception&) {
      continue;  // written whole, so never half: but a foreign file is not trusted, only redone
    }
    doc["scene_names"] = {name};
    e.tallies[name] = talliesFromJson(doc, run, f.string()).at(name);
  }
  return e;
}

// One finished scene into <out>.partial (run.json first, with the first scene).
void saveScene(const fs::path& out, const EvalRun& run, const std::string& name, const std::map<int, SceneTally>& byK) {
  const fs::path partial = partialDir(out);
  std::error_code ec;
  if (!fs::exists(partial / "run.json", ec)) {
    fs::create_directories(partial, ec);
    if (ec) throw Error("cannot create " + partial.string() + ": " + ec.message());
    ojson doc = {{"format", "spar-eval"}, {"version", 1}};
    doc.update(runJson(run));
    writeJson((partial / "run.json").string(), doc);
  }
  ojson doc = {{"scene", name}, {"tallies", {{name, ojson::object()}}}};
  for (const auto& [k, t] : byK) doc["tallies"][name][std::to_string(k)] = toJson(t);
  writeJson((partial / (name + ".json")).string(), doc);
}

// 1. The command line alone (exit 2): the mode of the run and its input-view counts.
struct EvalPlan {
  bool refine = false;
  std::vector<int> ks;
  std::string mode;
};

EvalPlan checkArgs(const EvalArgs& a) {
  if (a.noGating && a.assumeStatic) throw UsageError("--no-gating and --assume-static exclude each other");
  try {
    parsePrecision(a.precision);
  } catch (const Error& e) {
    throw UsageError(e.what());
  }
  if (a.maskSource != "raw" && a.maskSource != "refined") throw UsageError("--mask-source must be raw or refined");
  EvalPlan p;
  p.refine = a.refine || a.maskSource == "refined";
  if (p.refine && a.assumeStatic) throw UsageError("--refine / --mask-source refined and --assume-static exclude each other");
  if (a.maxScenes < 0) throw UsageError("--max-scenes must be at least 1");  // 0: all scenes
  p.ks = parseViews(a.views);
  p.mode = a.assumeStatic ? "assume-static" : a.noGating ? "no-gating" : a.maskSource == "refined" ? "refined-gating" : "default";
  return p;
}

// The scenes of this shard (--shard I/N: the scenes whose position, after --max-scenes, is I
// modulo N, so N processes of a batch system's job array together evaluate every scene once),
// all of one frame count and one set of class names (the prompts are encoded once).
std::vector<SceneInfo> shardScenes(const EvalArgs& a, const std::vector<int>& ks, size_t& setScenes) {
  std::vector<SceneInfo> all = discoverScenes(a.scenes, a.maxScenes), scenes;
  setScenes = all.size();
  for (size_t k = 0; k < all.size(); ++k)
    if (int(k % size_t(a.shards)) == a.shard) scenes.push_back(std::move(all[k]));
  if (scenes.empty())
    throw Error("shard " + std::to_string(a.shard) + "/" + std::to_string(a.shards) + " has no scenes (" +
                std::to_string(all.size()) + " in " + a.scenes + ")");
  const int frames = scenes.front().frames;
  for (const auto& s : scenes) {
    if (s.frames != frames)
      throw Error(s.name + " has " + std::to_string(s.frames) + " frames, " + scenes.front().name + " has " +
                  std::to_string(frames) + " (one F per test set)");
    if (s.classNames != scenes.front().classNames)
      throw Error(s.name + "/classes.json differs from " + scenes.front().name + "/classes.json");
  }
  for (int k : ks)
    if (k < 2 || k >= frames)
      throw UsageError("--views " + std::to_string(k) + ": need 2 .. " + std::to_string(frames - 1) +
                       " input views (at least one of the " + std::to_string(frames) + " frames must be a target)");
  return scenes;
}

// The size the scenes are evaluated at: --size (one the model runs at), else the model's; every
// scene must be that size (evaluation does not resize).
std::pair<int, int> evalSize(const EvalArgs& a, const Model& model, const std::vector<SceneInfo>& scenes) {
  if (a.height) {
    if (const std::string problem = model.sizeProblem(a.height, a.width); !problem.empty())
      throw UsageError("--size: " + problem);
  }
  const int h = int(a.height ? a.height : model.imageHeight()), w = int(a.width ? a.width : model.imageWidth());
  const std::string sizeText = std::to_string(h) + "x" + std::to_string(w) + " (HxW)";
  for (const auto& s : scenes)
    if (s.width != w || s.height != h)
      throw Error(s.name + " is " + std::to_string(s.height) + "x" + std::to_string(s.width) + " (HxW), the size " +
                  (a.height ? "--size gives" : "of the model") + " is " + sizeText + " (evaluation does not resize)");
  return {h, w};
}

struct Views {
  std::vector<int64_t> inputs, targets;
};

// One scene at one K: encode, render the targets, label maps; every metric against the scene's
// ground truth (PROTOCOL.md).
SceneTally scoreScene(const EvalArgs& a, const EvalRun& run, Session& session, const SceneData& data, const Views& v) {
  const int h = run.height, w = run.width;
  const size_t plane = size_t(h) * size_t(w);
  const bool semantic = run.semantic, refine = run.refine;
  const std::vector<std::string>& classNames = run.classNames;
  SceneTally t;
  if (semantic) t.semantic.emplace(int(classNames.size()));
  // Wall time of the model's work on this scene: encode, render, label maps on the host.
  const auto sceneStart = Clock::now();
  Request req;
  req.images = data.rgb;
  req.height = h;
  req.width = w;
  req.plan.views = run.frames;
  req.plan.inputs = v.inputs;
  req.plan.targets = v.targets;
  req.assumeStatic = a.assumeStatic;
  req.targetMotion = !a.assumeStatic;
  req.gating = !a.noGating;
  req.semanticFeatures = semantic;
  req.refine = refine;
  req.maskSource = a.maskSource == "refined" ? MaskSource::Refined : MaskSource::Raw;
  const Encoded& enc = session.encode(req);
  const std::vector<float> rgb = session.renderTargets();
  std::vector<std::vector<int32_t>> labels;
  if (semantic) labels = session.labelMaps(classNames);
  t.modelMs = msSince(sceneStart);

  const std::vector<float> meanColour = meanColourImage(data.rgb, v.inputs, h, w);
  for (size_t j = 0; j < v.targets.size(); ++j) {
    const size_t f = size_t(v.targets[j]);
    const float* gt = &data.rgb[f * 3 * plane];
    const uint8_t* dyn = &data.dynamic[f * plane];
    const float* copy = &data.rgb[size_t(nearestInput(v.targets[j], v.inputs)) * 3 * plane];
    ++t.targetViews;
    if (const auto p = staticPsnr(&rgb[j * 3 * plane], gt, dyn, h, w)) {
      t.psnrSum += *p, ++t.psnrViews;
      t.copyPsnrSum += *staticPsnr(copy, gt, dyn, h, w);
      t.meanPsnrSum += *staticPsnr(meanColour.data(), gt, dyn, h, w);
    }
    if (const auto s = staticSsim(&rgb[j * 3 * plane], gt, dyn, h, w)) {
      t.ssimSum += *s, ++t.ssimViews;
      t.copySsimSum += *staticSsim(copy, gt, dyn, h, w);
    }
    if (semantic) t.semantic->add(labels[j].data(), &data.classes[f * plane], dyn, h, w);
  }
  // Masks of every frame (inputs, then targets) against the scene's ground truth.
  auto addMasks = [&](MaskCounts& counts, const std::vector<float>& input, const std::vector<float>& target) {
    for (size_t j = 0; j < v.inputs.size(); ++j)
      counts.add(&input[j * plane], &data.dynamic[size_t(v.inputs[j]) * plane], plane, kMaskThreshold);
    for (size_t j = 0; j < v.targets.size(); ++j)
      counts.add(&target[j * plane], &data.dynamic[size_t(v.targets[j]) * plane], plane, kMaskThreshold);
  };
  if (!a.assumeStatic) addMasks(t.masks, enc.motionInput, enc.motionTarget);
  // the refined masks hold 0 or 1: the same threshold reads them
  if (refine) addMasks(t.refinedMasks, enc.refinedInput, enc.refinedTarget);
  t.seconds = msSince(sceneStart) / 1000.0;
  return t;
}

}  // namespace

void runEval(const EvalArgs& a) {
  takeWarnings();  // the results page lists this evaluation's warnings only
  const auto start = Clock::now();
  const EvalPlan plan = checkArgs(a);
  // 2. Files (exit 1), cheapest first: nothing heavy is loaded before everything named exists.
  if (!fs::exists(a.model)) throw Error("model not found: " + a.model);
  const fs::path outPath = checkResultPath(a.out);
  size_t setScenes = 0;
  const std::vector<SceneInfo> scenes = shardScenes(a, plan.ks, setScenes);
  const Model model = Model::open(a.model);
  if (const std::string problem = plan.refine ? model.refinementProblem() : ""; !problem.empty())
    throw Error(problem + ": --refine / --mask-source refined are not available");
  const auto [h, w] = evalSize(a, model, scenes);
  // Semantic metrics only for models that decode semantics; those need the CLIP tokenizer.
  const std::vector<std::string>& classNames = scenes.front().classNames;
  if (model.semantic()) warnAboutPrompts(model.promptWarnings(classNames), classNames.size());

  EvalRun run;
  run.model = absolutePath(a.model);
  run.scenesDir = absolutePath(a.scenes);
  run.modelDigest = modelDigest(a.model);
  run.modelBytes = model.fileBytes();
  run.precision = a.precision;
  run.mode = plan.mode;
  run.refine = plan.refine;
  run.semantic = model.semantic();
  run.frames = scenes.front().frames;
  run.height = h;
  run.width = w;
  run.views = plan.ks;
  run.classNames = classNames;
  run.setScenes = int(setScenes);
  run.shard = a.shard;
  run.shards = a.shards;
  std::vector<std::string> names;
  for (const auto& s : scenes) names.push_back(s.name);
  // What an earlier run of this command finished (docs/many-scenes.md, "Reruns"): a complete
  // result.json of the same run, else the scenes an interrupted run left in <out>.partial.
  Earlier earlier = earlierWork(outPath, run, names, a.redo);
  if (earlier.complete) {
    std::fprintf(stderr, "spar eval: %s already holds this evaluation (%zu scenes): nothing to do (--redo evaluates "
                 "again)\n", outPath.string().c_str(), names.size());
    printTable(run, earlier.tallies, "an earlier run");
    return;
  }
  Tallies tallies = std::move(earlier.tallies);
  std::map<int, Views> views;
  for (int k : plan.ks) {
    Views& v = views[k];
    v.inputs = inputPositions(run.frames, k);
    for (int64_t f = 0; f < run.frames; ++f)
      if (std::find(v.inputs.begin(), v.inputs.end(), f) == v.inputs.end()) v.targets.push_back(f);
  }

  Progress progress;
  std::string deviceName = "-";
  try {
    for (const std::string& name : names)
      if (tallies.count(name))
        std::fprintf(stderr, "spar eval: %s was finished by an earlier run (%s): not evaluated again\n", name.c_str(),
                     partialDir(outPath).string().c_str());
    if (tallies.size() < scenes.size()) {
      progress.step("opening the Vulkan device");
      EngineOptions eo;
      eo.device = a.device;
      eo.pipelineCacheFile = pipelineCachePath();
      Context context(EngineOptions::fromEnvironment(eo));
      deviceName = context.deviceName();
      SessionOptions so;
      so.profile = false;
      so.precision = parsePrecision(a.precision);
      Session session(context, model, so);  // once: weights stay on the device for every scene
      if (run.semantic) {
        progress.step("encoding " + std::to_string(classNames.size()) + " class names");
        session.preparePrompts(classNames);
      }
      // Scenes outer, K inner: each scene is read once.
      for (size_t si = 0; si < scenes.size(); ++si) {
        const SceneInfo& scene = scenes[si];
        if (tallies.count(scene.name)) continue;
        const SceneData data = loadScene(scene);
        std::map<int, SceneTally> byK;
        for (int k : plan.ks) {
          progress.step("scene " + std::to_string(si + 1) + "/" + std::to_string(scenes.size()) + " " + scene.name +
                        ", K=" + std::to_string(k) + " (" + plan.mode + ")");
          byK[k] = scoreScene(a, run, session, data, views[k]);
        }
        // Kept as soon as it is done: a run killed later (a batch system's time limit, a
        // lost node) resumes after it.
        saveScene(outPath, run, scene.name, byK);
        tallies[scene.name] = std::move(byK);
      }
    }
    progress.finish();
  } catch (...) {
    progress.finish();
    throw;
  }

  // result.json (PROTOCOL.md, "Output JSON"), then the finished scenes' files are not needed.
  writeResult(outPath.string(), resultDocument(run, tallies), deviceName, takeWarnings());
  std::error_code ec;
  fs::remove_all(partialDir(outPath), ec);
  printTable(run, tallies, deviceName);
  std::printf("wrote %s in %.1f s\n", outPath.string().c_str(), msSince(start) / 1000.0);
}

}  // namespace spar::cli
