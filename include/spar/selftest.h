// The self-test (`spar selftest`): the engine checked on one device and driver. Every op family
// the device's kernel plan uses runs on odd and stiff shapes against float64 computed on the
// host, then the self-test model (a small SPAR shipped with its float64 reference outputs) runs
// stage by stage, all under the validation layer where it is installed. docs/portability.md
// explains the checks and their thresholds.
#pragma once
#include <cstddef>
#include <string>
#include <vector>

#include "spar/context.h"
#include "spar/export.h"

namespace spar {

struct SelftestCheck {
  std::string name;    // e.g. "linear 77x150x72 +bias GELU"
  std::string family;  // the kernel family the plan chose for it ("cpu", "tiled", "-")
  double nmse = 0, maxAbs = 0;          // measured against float64
  double maxNmse = 0, maxAbsLimit = 0;  // the thresholds (the tests use the same per op)
  double ms = 0;                        // wall time of the check's device work, builds included
  bool finite = true;
  std::string error;   // an exception's message, when the op failed to run
  std::string detail;  // shown instead of the error columns (a motion mask: pixels differing)
  bool passed() const { return error.empty() && finite && nmse <= maxNmse && maxAbs <= maxAbsLimit; }
};

struct SelftestReport {
  std::string device;          // the device's name and driver ("llvmpipe (...), Mesa 22.3.6 (LLVM 15.0.6)")
  std::string error;           // the device could not be used (nothing else ran on it)
  DeviceInfo info;             // after any device-limit profile
  std::string profile;         // the profile's description, "" without one
  std::vector<std::string> plan;
  std::vector<SelftestCheck> opChecks, modelChecks;
  std::string modelDir;        // "" when the self-test model was not found (a failing check says so)
  bool validation = false;     // the validation layer was on
  std::string validationNote;  // why it was off
  size_t validationMessages = 0;

  size_t total() const { return opChecks.size() + modelChecks.size(); }
  size_t passed() const {
    size_t n = 0;
    for (const auto* list : {&opChecks, &modelChecks})
      for (const SelftestCheck& c : *list) n += c.passed();
    return n;
  }
  bool ok() const { return error.empty() && passed() == total() && validationMessages == 0; }
};

// Runs the self-test on `device` (an index or part of a name, as EngineOptions::device; "": the
// environment's SPAR_DEVICE, else the default choice) with the self-test model in `modelDir`
// ("": $SPAR_SELFTEST_DATA, else share/spar/selftest of the installed package, else the source
// tree's data/selftest). Throws spar::Error when the device cannot be used.
SPAR_API SelftestReport runSelftestOn(const std::string& device, const std::string& modelDir);

}  // namespace spar
