#include "samples/spar_modes/modes.h"

#include <algorithm>
#include <chrono>
#include <map>
#include <optional>
#include <sstream>

#include "engine/error.h"
#include "model/prompt_label_maps.h"

namespace spar::modes {
namespace {

using Clock = std::chrono::steady_clock;

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

// One encode + render (+ label maps with prompts); returns its wall time in ms.
double runOnce(Engine& engine, SparPipeline& pipe, const SparRequest& request, const PromptEmbeddings* text,
               ModeRun& out) {
  const auto t0 = Clock::now();
  const SparEncoded& e = pipe.encode(request);
  out.motion = e.motionInput;
  out.refined = e.refinedInput;
  out.rgb = pipe.renderTargets();
  if (text) {
    out.labels.clear();
    for (const std::vector<int32_t>& map : computeLabelMaps(engine, pipe.renderedFeatures(), *text).maps)
      out.labels.insert(out.labels.end(), map.begin(), map.end());
  }
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

}  // namespace

const std::vector<Mode>& allModes() {
  static const std::vector<Mode> modes = {
      {"fp32", DType::F32, false},
      {"fp16", DType::F16, false},
      {"fp32-static", DType::F32, true},
      {"fp16-static", DType::F16, true},
      // quantized matrices (converter/FORMAT.md, "Quantized matrices"), quantized at upload
      {"q8", DType::Q8, false},
      {"q4", DType::Q4, false},
      {"q8-static", DType::Q8, true},
      {"q4-static", DType::Q4, true},
      // SAM2.1 refinement: the masks refined, CV-DRP's still gating (-refine), or the refined
      // ones gating (-refined, the official mask_source: refined)
      {"fp32-refine", DType::F32, false, true, false},
      {"fp16-refine", DType::F16, false, true, false},
      {"fp32-refined", DType::F32, false, true, true},
      {"fp16-refined", DType::F16, false, true, true},
  };
  return modes;
}

std::vector<Mode> selectModes(const std::string& list, bool sam2) {
  std::vector<Mode> out;
  if (list.empty()) {
    for (const Mode& m : allModes())
      if (sam2 || !m.refine) out.push_back(m);
    return out;
  }
  std::string names;
  for (const Mode& m : allModes()) names += (names.empty() ? "" : ", ") + m.name;
  std::stringstream ss(list);
  for (std::string name; std::getline(ss, name, ',');) {
    auto it = std::find_if(allModes().begin(), allModes().end(), [&](const Mode& m) { return m.name == name; });
    if (it == allModes().end()) throw Error("unknown mode '" + name + "' (modes: " + names + ")");
    if (it->refine && !sam2)
      throw Error("mode " + name + " needs a model packed with SAM2.1 (spar-convert --sam2)");
    out.push_back(*it);
  }
  if (out.empty()) throw Error("no mode selected");
  return out;
}

ModeRun runMode(const EngineOptions& engineOptions, const PackedModel& model, const SparRequest& request,
                const Mode& mode, int repeats, const Prompts& prompts) {
  Engine engine(engineOptions);
  SparPipeline pipe(engine, model, {.profile = true, .keepIntermediates = false, .weightType = mode.weightType});
  std::optional<PromptEmbeddings> text;
  if (prompts.count)
    text = encodePrompts(engine, model, pipe.config(), mode.weightType, prompts.ids, prompts.count);
  SparRequest req = request;
  req.semanticFeatures = prompts.count > 0;
  req.assumeStatic = mode.assumeStatic;
  req.refine = mode.refine;
  req.maskSource = mode.refinedGating ? MaskSource::Refined : MaskSource::Raw;
  req.targetMotion = false;

  ModeRun out;
  out.mode = mode;
  out.device = engine.caps().name;
  out.repeats = repeats;
  const PromptEmbeddings* textPtr = text ? &*text : nullptr;
  out.firstRunMs = runOnce(engine, pipe, req, textPtr, out);

  // stageTimes() accumulates since construction: each run's share is the difference.
  std::vector<StageTime> before = pipe.stageTimes();
  std::map<std::string, std::vector<double>> gpu, wall;
  std::vector<double> totalWall, totalGpu;
  for (int r = 0; r < repeats; ++r) {
    totalWall.push_back(runOnce(engine, pipe, req, textPtr, out));
    const std::vector<StageTime>& now = pipe.stageTimes();
    double sum = 0;
    for (const StageTime& s : now) {
      auto prev = std::find_if(before.begin(), before.end(), [&](const StageTime& b) { return b.name == s.name; });
      const double g = s.gpuMs - (prev == before.end() ? 0.0 : prev->gpuMs);
      const double w = s.wallMs - (prev == before.end() ? 0.0 : prev->wallMs);
      gpu[s.name].push_back(g);
      wall[s.name].push_back(w);
      sum += g;
    }
    totalGpu.push_back(sum);
    before = now;
  }
  for (const StageTime& s : pipe.stageTimes()) out.stages.push_back({s.name, median(gpu[s.name]), median(wall[s.name])});
  out.wallMs = median(totalWall);
  out.gpuMs = median(totalGpu);
  out.weightBytes = pipe.weightBytesLoaded();
  out.devicePeakBytes = engine.memory().peakBytes();
  return out;
}

}  // namespace spar::modes
