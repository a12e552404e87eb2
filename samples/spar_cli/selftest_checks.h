// The checks of `spar selftest` (selftest_command.h): one op family each, on odd sizes and
// stiff values, against a float64 reference computed here on the host from the same fp32 inputs.
#pragma once
#include <functional>
#include <string>
#include <vector>

#include "engine/engine.h"

namespace spar::cli {

struct SelftestCheck {
  std::string name;   // e.g. "linear 77x150x72 +bias GELU"
  std::string family; // the kernel family the plan chose for it ("cpu", "tiled", "-")
  double nmse = 0, maxAbs = 0;           // measured against float64
  double maxNmse = 0, maxAbsLimit = 0;   // the thresholds (tests/ use the same per op)
  double ms = 0;                         // wall time of the check's device work, build included
  bool finite = true;
  std::string error;  // an exception's message, when the op failed to run
  std::string detail; // shown instead of the error columns (a motion mask: pixels differing)
  bool passed() const { return error.empty() && finite && nmse <= maxNmse && maxAbs <= maxAbsLimit; }
};

// `got` against float64 `want` into c: NMSE, max abs error, finiteness (the op checks and the
// self-test model's stages measure alike).
void measureAgainst(SelftestCheck& c, const std::vector<float>& got, const std::vector<double>& want);

// Runs every check on `engine` (each in its own recorder, in order).
std::vector<SelftestCheck> runSelftestChecks(Engine& engine);

}  // namespace spar::cli
