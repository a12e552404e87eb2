// Shared by the tests that run the built `spar` program: its path SPAR_CLI, which
// tools/CMakeLists.txt defines for the test targets it lists (spar_wire_render_test), and the
// helpers they use to run it (runValidated, probeVideo: tests/test_support.h).
#pragma once
#ifndef SPAR_CLI
#error "SPAR_CLI (path of the built spar binary) is defined by tools/CMakeLists.txt"
#endif

#include "tests/test_support.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <string>

namespace spar::test {

// report.json's device_memory (model/memory_estimate.h) against the run's measured peak: the
// lower bound at most the peak and not a loose one (>= 0.4x), the upper bound at least the
// peak and within kMemoryUpperSlack times it, and the estimate's weights exactly what the run
// loaded (weights_bytes_loaded). JSON: nlohmann's json or ordered_json.
constexpr double kMemoryUpperSlack = 1.5;
template <class Json>
void expectMemoryBounds(const Json& report, const std::string& what) {
  const double upperSlack = kMemoryUpperSlack;
  const Json& m = report.at("device_memory");
  const double lower = m.at("estimated_min_bytes").template get<double>(),
               upper = m.at("estimated_max_bytes").template get<double>(), peak = m.at("peak_bytes").template get<double>();
  std::printf("  %s: device memory peak %.2f MiB, estimated %.2f to %.2f MiB (upper / peak %.3f)\n", what.c_str(),
              peak / (1 << 20), lower / (1 << 20), upper / (1 << 20), upper / peak);
  EXPECT_LE(lower, peak) << what;
  EXPECT_GE(lower, 0.4 * peak) << what;
  EXPECT_GE(upper, peak) << what;
  EXPECT_LE(upper, upperSlack * peak) << what;
  EXPECT_EQ(m.at("estimated_weight_bytes"), report.at("weights_bytes_loaded")) << what;
}

}  // namespace spar::test
