// spar selftest: what a user runs to check the engine on their device and driver. Prints the
// device, driver, limits (after any device-limit profile) and the kernel plan, then runs every
// op family the plan uses on odd and stiff shapes against float64 computed on the host
// (selftest/selftest_checks.cpp) and the self-test model stage by stage against the
// float64 reference outputs it ships with (selftest/selftest_model.cpp), each check's
// error, threshold and time, the validation layer's messages, and a verdict. Exit 0 only if every check passed and the layer (when
// installed) said nothing.
#pragma once
#include <string>

namespace spar::cli {

struct SelftestArgs {
  std::string device;  // --device
  bool json = false;   // --json: the report as JSON on stdout instead of the table
  std::string model;   // --model-dir: the self-test model's directory ("" = findSelftestModel's places)
  std::string junit;   // --junit FILE: the checks as JUnit XML too (selftest_junit.h)
  bool allDevices = false;  // --all-devices: every device, SwiftShader's too where installed, as
                            // one table with a column per device (selftest_table.h)
};

// Returns true when everything passed (on every device).
bool runSelftest(const SelftestArgs& args);

}  // namespace spar::cli
