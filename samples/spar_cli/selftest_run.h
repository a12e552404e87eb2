// One device's `spar selftest` (selftest_command.h): the engine on it with the validation layer
// where installed, its limits and kernel plan, the op checks (selftest_checks.h) and the
// self-test model stage by stage (selftest_model.h), what the table, JSON and JUnit reports print.
#pragma once
#include <cstddef>
#include <string>
#include <vector>

#include "engine/device.h"
#include "samples/spar_cli/selftest_checks.h"

namespace spar::cli {

struct SelftestReport {
  std::string device;        // the device's name and driver ("llvmpipe (...), Mesa 22.3.6 (LLVM 15.0.6)")
  std::string error;         // the device could not be used (--all-devices: nothing else ran on it)
  DeviceCaps caps;           // after any device-limit profile
  std::string profile;       // the profile's description, "" without one
  std::vector<std::string> plan;
  std::vector<SelftestCheck> opChecks, modelChecks;
  std::string modelDir;      // "" when the self-test model was not found (a failing check says so)
  bool validation = false;   // the validation layer was on
  std::string validationNote;  // why it was off
  size_t validationMessages = 0;

  size_t total() const { return opChecks.size() + modelChecks.size(); }
  size_t passed() const;
  bool ok() const { return error.empty() && passed() == total() && validationMessages == 0; }
};

// Runs the self-test on `device` (an index or part of a name, as --device; "" = SPAR_DEVICE, else
// the default choice) with the self-test model from `modelDir` (--model-dir; "" = its default
// places). Throws spar::Error when the device cannot be used.
SelftestReport runSelftestOn(const std::string& device, const std::string& modelDir);

}  // namespace spar::cli
