// `spar selftest --junit FILE`: the self-test as a JUnit XML report, what a driver's CI reads
// (one testcase per check, with its kernel family, error, thresholds and time; a failed check
// is a <failure>; the validation layer's messages are one more testcase). Written whole: a
// temporary name beside FILE, then a rename.
#pragma once
#include <string>
#include <vector>

#include "spar/selftest.h"

namespace spar::cli {

// One <testsuite> per device (--all-devices: several); a device that could not be used is one
// failing testcase in its suite. Throws spar::Error naming the file when it cannot be written.
void writeSelftestJunit(const std::string& path, const std::vector<SelftestReport>& reports);
// Throws the same error before any work when `path`'s directory is missing or not writable.
void checkJunitWritable(const std::string& path);

}  // namespace spar::cli
