// The precisions and shortcuts the engine offers, run one at a time on the same request, with
// what each costs in time and memory (tools/spar_modes/main.cpp reports them side by side).
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "spar/engine_options.h"
#include "spar/model.h"
#include "spar/precision.h"
#include "spar/request.h"

namespace spar::modes {

struct Mode {
  std::string name;                // "fp32", "fp16", "fp32-static", ..., "fp16-refined"
  Precision precision = Precision::FP32;  // SessionOptions::precision
  bool assumeStatic = false;       // Request::assumeStatic (no DINOv3, no CV-DRP)
  bool refine = false;             // Request::refine: SAM2.1 refines the inputs' masks
  bool refinedGating = false;      // MaskSource::Refined: its hard masks gate the tokens
};

// Every mode, in report order (the refine modes need a model packed with SAM2.1).
const std::vector<Mode>& allModes();
// The modes named in a comma-separated list ("" = all, the refine modes only when `sam2`);
// throws spar::Error for unknown names, and for a refine mode without `sam2`.
std::vector<Mode> selectModes(const std::string& list, bool sam2);

struct StageStat {
  std::string name;
  double gpuMs = 0, wallMs = 0;  // medians over the measured runs
};

struct ModeRun {
  Mode mode;
  std::string device;             // the device's name
  std::vector<StageStat> stages;  // in the order the stages ran
  double wallMs = 0;       // median per run: encode + render, host copies included
  double gpuMs = 0;        // median per run: sum of the stages' dispatch timestamps
  double firstRunMs = 0;   // the first run: weight uploads and first-use shader compilation too
  int repeats = 0;
  uint64_t weightBytes = 0;      // weights uploaded (Session::weightBytesLoaded)
  uint64_t devicePeakBytes = 0;  // peak device memory in use (weights, activations, scratch)
  std::vector<float> rgb;        // [T, 3, H, W] of the last run
  std::vector<float> motion;     // [K, H, W] P(dynamic) of the inputs (empty when static)
  std::vector<float> refined;    // [K, H, W] SAM2.1's refined masks, 0 or 1 (refine modes)
  std::vector<int32_t> labels;   // [T, H, W] label maps of the targets (with prompts), last run
};

// Runs `mode` on a fresh engine (so its device memory and compiled kernels are its own): one
// first run, then `repeats` measured runs of encode() + renderTargets(), and with prompts the
// targets' label maps (the prompts encoded once per mode, before the first run, as `spar render`
// does; the text encoder's weights in the mode's precision).
ModeRun runMode(const EngineOptions& engineOptions, const Model& model, const Request& request, const Mode& mode,
                int repeats, const std::vector<std::string>& prompts = {});

}  // namespace spar::modes
