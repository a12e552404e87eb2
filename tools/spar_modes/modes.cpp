#include "tools/spar_modes/modes.h"

#include <algorithm>
#include <chrono>
#include <map>
#include <optional>
#include <sstream>

#include "spar/error.h"
#include "spar/session.h"

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
double runOnce(Session& session, const Request& request, const std::vector<std::string>& prompts, ModeRun& out) {
  const auto t0 = Clock::now();
  const Encoded& e = session.encode(request);
  out.motion = e.motionInput;
  out.refined = e.refinedInput;
  out.rgb = session.renderTargets();
  if (!prompts.empty()) {
    out.labels.clear();
    for (const std::vector<int32_t>& map : session.labelMaps(prompts))
      out.labels.insert(out.labels.end(), map.begin(), map.end());
  }
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

}  // namespace

const std::vector<Mode>& allModes() {
  static const std::vector<Mode> modes = {
      {"fp32", Precision::FP32, false},
      {"fp16", Precision::FP16, false},
      {"fp32-static", Precision::FP32, true},
      {"fp16-static", Precision::FP16, true},
      // quantized matrices (converter/FORMAT.md, "Quantized matrices"), quantized at upload
      {"q8", Precision::Q8, false},
      {"q4", Precision::Q4, false},
      {"q8-static", Precision::Q8, true},
      {"q4-static", Precision::Q4, true},
      // SAM2.1 refinement: the masks refined, CV-DRP's still gating (-refine), or the refined
      // ones gating (-refined, the official mask_source: refined)
      {"fp32-refine", Precision::FP32, false, true, false},
      {"fp16-refine", Precision::FP16, false, true, false},
      {"fp32-refined", Precision::FP32, false, true, true},
      {"fp16-refined", Precision::FP16, false, true, true},
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

ModeRun runMode(const EngineOptions& engineOptions, const Model& model, const Request& request, const Mode& mode,
                int repeats, const std::vector<std::string>& prompts) {
  Context context(engineOptions);
  SessionOptions so;
  so.precision = mode.precision;
  Session session(context, model, so);
  if (!prompts.empty()) session.preparePrompts(prompts);
  Request req = request;
  req.semanticFeatures = !prompts.empty();
  req.assumeStatic = mode.assumeStatic;
  req.refine = mode.refine;
  req.maskSource = mode.refinedGating ? MaskSource::Refined : MaskSource::Raw;
  req.targetMotion = false;

  ModeRun out;
  out.mode = mode;
  out.device = context.deviceName();
  out.repeats = repeats;
  out.firstRunMs = runOnce(session, req, prompts, out);

  // stageTimes() accumulates since construction: each run's share is the difference.
  std::vector<StageTime> before = session.stageTimes();
  std::map<std::string, std::vector<double>> gpu, wall;
  std::vector<double> totalWall, totalGpu;
  for (int r = 0; r < repeats; ++r) {
    totalWall.push_back(runOnce(session, req, prompts, out));
    const std::vector<StageTime>& now = session.stageTimes();
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
  for (const StageTime& s : session.stageTimes()) out.stages.push_back({s.name, median(gpu[s.name]), median(wall[s.name])});
  out.wallMs = median(totalWall);
  out.gpuMs = median(totalGpu);
  out.weightBytes = session.weightBytesLoaded();
  out.devicePeakBytes = context.memory().peakBytes;
  return out;
}

}  // namespace spar::modes
