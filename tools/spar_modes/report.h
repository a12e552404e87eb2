// The side-by-side report of every mode: a markdown table (stdout), a JSON document and the
// data of the error-vs-time plot.
#pragma once
#include <nlohmann/json.hpp>

#include <optional>
#include <string>
#include <vector>

#include "tools/spar_modes/accuracy.h"
#include "tools/spar_modes/modes.h"

namespace spar::modes {

struct ModeResult {
  ModeRun run;
  // Against the fp32 reference of the whole model (DINOv3 and CV-DRP on): what the mode costs.
  RgbError vsReference;
  std::optional<double> maskAgreement;  // input motion masks (nullopt with assume-static)
  std::optional<double> motionMaxAbs;
  // SAM2.1's refined input masks against the reference's refinement (refine modes)
  std::optional<double> refinedAgreement;
  // the targets' label maps against the reference's (with prompts)
  std::optional<double> labelAgreement;
  // Against the reference run in the same mode (--assume-static for the static modes,
  // --mask-source refined for the refined-gating ones): the engine's own error, without what
  // the shortcut itself changes.
  RgbError vsSameMode;
};

struct ReportSetup {
  std::string model, device;
  uint64_t modelFileBytes = 0;
  std::string fileWeights;  // "F32" or "F16": how the packed file stores the matrices
  std::vector<std::string> frames;
  std::vector<int64_t> inputs, targets;
  int64_t height = 0, width = 0;
  std::string reference, referenceStatic, referenceRefine;  // goldens directories ("" if not run)
  double referenceMs = 0, referenceStaticMs = 0, referenceRefineMs = 0;
  std::vector<std::string> labels;  // the prompts ("" = none)
};

nlohmann::ordered_json reportJson(const ReportSetup& setup, const std::vector<ModeResult>& results);
std::string reportMarkdown(const ReportSetup& setup, const std::vector<ModeResult>& results);

}  // namespace spar::modes
