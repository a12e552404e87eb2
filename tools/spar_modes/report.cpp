#include "tools/spar_modes/report.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>

namespace spar::modes {
namespace {

namespace fs = std::filesystem;

// JSON has no infinity (identical outputs): null, as for "not applicable".
nlohmann::ordered_json number(double v) { return std::isfinite(v) ? nlohmann::ordered_json(v) : nullptr; }
nlohmann::ordered_json number(const std::optional<double>& v) { return v ? number(*v) : nullptr; }

std::string fmt(const char* format, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, format, v);
  return buf;
}
std::string psnr(double db) { return std::isfinite(db) ? fmt("%.1f", db) : "identical"; }
std::string mb(uint64_t bytes) { return fmt("%.2f", double(bytes) / 1e6); }

// Stage names in the order they first ran in any mode.
std::vector<std::string> stageNames(const std::vector<ModeResult>& results) {
  std::vector<std::string> names;
  for (const ModeResult& r : results)
    for (const StageStat& s : r.run.stages)
      if (std::find(names.begin(), names.end(), s.name) == names.end()) names.push_back(s.name);
  return names;
}

const StageStat* findStage(const ModeRun& run, const std::string& name) {
  for (const StageStat& s : run.stages)
    if (s.name == name) return &s;
  return nullptr;
}

// The matrices' type as the engine names dtypes: "f32", "f16", "q8", "q4".
std::string weightsName(Precision p) {
  const std::string name = precisionName(p);
  return name.rfind("fp", 0) == 0 ? "f" + name.substr(2) : name;
}

}  // namespace

nlohmann::ordered_json reportJson(const ReportSetup& setup, const std::vector<ModeResult>& results) {
  nlohmann::ordered_json modes = nlohmann::ordered_json::array();
  for (const ModeResult& r : results) {
    nlohmann::ordered_json stages = nlohmann::ordered_json::array();
    for (const StageStat& s : r.run.stages) stages.push_back({{"name", s.name}, {"gpu_ms", s.gpuMs}, {"wall_ms", s.wallMs}});
    modes.push_back({
        {"mode", r.run.mode.name},
        {"weights", weightsName(r.run.mode.precision)},
        {"assume_static", r.run.mode.assumeStatic},
        {"refine", r.run.mode.refine},
        {"refined_gating", r.run.mode.refinedGating},
        {"repeats", r.run.repeats},
        {"wall_ms", r.run.wallMs},
        {"gpu_ms", r.run.gpuMs},
        {"first_run_ms", r.run.firstRunMs},
        {"weight_bytes", r.run.weightBytes},
        {"device_peak_bytes", r.run.devicePeakBytes},
        {"stages", stages},
        {"vs_reference",
         {{"rgb_psnr_db", number(r.vsReference.psnrDb)},
          {"rgb_max_abs", r.vsReference.maxAbs},
          {"mask_agreement", number(r.maskAgreement)},
          {"motion_max_abs", number(r.motionMaxAbs)},
          {"refined_mask_agreement", number(r.refinedAgreement)},
          {"label_map_agreement", number(r.labelAgreement)}}},
        {"vs_same_mode_reference",
         {{"rgb_psnr_db", number(r.vsSameMode.psnrDb)}, {"rgb_max_abs", r.vsSameMode.maxAbs}}},
    });
  }
  return {
      {"tool", "spar-modes"},
      {"device", setup.device},
      {"model", setup.model},
      {"model_file_bytes", setup.modelFileBytes},
      {"file_matrices", setup.fileWeights},
      {"frames", setup.frames},
      {"inputs", setup.inputs},
      {"targets", setup.targets},
      {"image", {setup.height, setup.width}},
      {"labels", setup.labels},
      {"reference",
       {{"precision", "fp32"},
        {"goldens", setup.reference},
        {"goldens_assume_static", setup.referenceStatic},
        {"goldens_refine", setup.referenceRefine},
        {"model_ms", setup.referenceMs},
        {"model_ms_assume_static", setup.referenceStaticMs},
        {"model_ms_refine", setup.referenceRefineMs}}},
      {"modes", modes},
  };
}

std::string reportMarkdown(const ReportSetup& setup, const std::vector<ModeResult>& results) {
  std::string s = "## spar-modes: " + setup.model + " (" + std::to_string(setup.frames.size()) + " frames, " +
                  std::to_string(setup.inputs.size()) + " inputs, " + std::to_string(setup.targets.size()) +
                  " targets, " + std::to_string(setup.width) + "x" + std::to_string(setup.height) + ") on " +
                  setup.device + "\n\n";
  s += "Error against the PyTorch fp32 reference of the whole model (DINOv3 + CV-DRP on); times are medians of " +
       std::to_string(results.empty() ? 0 : results[0].run.repeats) +
       " runs of encode + render after a first run (weight upload, shader compilation).\n\n";
  const bool labels = !setup.labels.empty();
  if (labels) {
    s += "Label maps of the targets for " + std::to_string(setup.labels.size()) + " prompts (";
    for (size_t i = 0; i < setup.labels.size(); ++i) s += (i ? ", " : "") + setup.labels[i];
    s += "), in every mode's wall time.\n\n";
  }
  s += "| mode | wall ms | GPU ms | first run ms | weights MB | device peak MB | RGB PSNR dB | RGB max abs | mask "
       "agreement % | refined mask agreement % |" + std::string(labels ? " label agreement % |" : "") +
       " PSNR vs same-mode ref dB |\n";
  s += std::string("|---|---|---|---|---|---|---|---|---|---|") + (labels ? "---|" : "") + "---|\n";
  for (const ModeResult& r : results) {
    s += "| " + r.run.mode.name + " | " + fmt("%.1f", r.run.wallMs) + " | " + fmt("%.1f", r.run.gpuMs) + " | " +
         fmt("%.0f", r.run.firstRunMs) + " | " + mb(r.run.weightBytes) + " | " + mb(r.run.devicePeakBytes) + " | " +
         psnr(r.vsReference.psnrDb) + " | " + fmt("%.2e", r.vsReference.maxAbs) + " | " +
         (r.maskAgreement ? fmt("%.3f", 100.0 * *r.maskAgreement) : std::string("n/a (no CV-DRP)")) + " | " +
         (r.refinedAgreement ? fmt("%.3f", 100.0 * *r.refinedAgreement) : std::string("-")) + " | " +
         (labels ? (r.labelAgreement ? fmt("%.3f", 100.0 * *r.labelAgreement) : std::string("-")) + " | " : std::string()) +
         psnr(r.vsSameMode.psnrDb) + " |\n";
  }
  s += "\nPer stage, wall / GPU ms (median):\n\n| stage |";
  std::string rule = "|---|";
  for (const ModeResult& r : results) {
    s += " " + r.run.mode.name + " |";
    rule += "---|";
  }
  s += "\n" + rule + "\n";
  for (const std::string& name : stageNames(results)) {
    s += "| " + name + " |";
    for (const ModeResult& r : results) {
      const StageStat* st = findStage(r.run, name);
      s += st ? " " + fmt("%.1f", st->wallMs) + " / " + fmt("%.1f", st->gpuMs) + " |" : std::string(" — |");
    }
    s += "\n";
  }
  s += "\nPyTorch fp32 reference (CPU, its model stages; goldens run, which also records every layer): " +
       fmt("%.0f", setup.referenceMs) + " ms, with --assume-static " + fmt("%.0f", setup.referenceStaticMs) + " ms" +
       (setup.referenceRefine.empty() ? std::string()
                                      : ", with SAM2.1's refinement (" + fs::path(setup.referenceRefine).filename().string() +
                                            ") " + fmt("%.0f", setup.referenceRefineMs) + " ms") +
       ". Packed file: " + mb(setup.modelFileBytes) + " MB, matrices stored " + setup.fileWeights + ".\n";
  return s;
}

}  // namespace spar::modes
