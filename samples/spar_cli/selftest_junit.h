// `spar selftest --junit FILE`: the self-test as a JUnit XML report, what a driver's CI reads
// (one testcase per check, with its kernel family, error, thresholds and time; a failed check
// is a <failure>; the validation layer's messages are one more testcase). Written whole: a
// temporary name beside FILE, then a rename.
#pragma once
#include <cstddef>
#include <string>
#include <vector>

#include "samples/spar_cli/selftest_checks.h"

namespace spar::cli {

struct SelftestReport {
  std::string device;                                   // the device's name and driver
  std::vector<SelftestCheck> opChecks, modelChecks;
  bool validation = false;                              // the validation layer was on
  size_t validationMessages = 0;
};

// Throws spar::Error naming the file when it cannot be written.
void writeSelftestJunit(const std::string& path, const SelftestReport& report);
// Throws the same error before any work when `path`'s directory is missing or not writable.
void checkJunitWritable(const std::string& path);

}  // namespace spar::cli
