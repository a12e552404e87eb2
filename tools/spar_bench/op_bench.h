// spar-bench's op cases (bench_cases.h) timed on one device: per case the median GPU time of
// `repeats` runs, GFLOPS (or GB/s) and NMSE against float64, with the first run's pipeline
// creation and driver build apart; with `peer`, the same ops timed on the CPU (bench_peer.h).
// The only part of the programs that records single ops (through engine/internal_ops.h).
#pragma once
#include <nlohmann/json.hpp>

#include <string>

#include "spar/engine_options.h"

namespace spar::bench {

struct OpBenchArgs {
  std::string only;    // cases whose name contains this
  bool large = false;  // the 4096^3 GEMMs too (always on GPUs)
  int repeats = 5;
  bool peer = false;
  bool json = false;   // the table on stdout unless json
};

// The report (device, kernel plan, one entry per op). Throws spar::Error.
nlohmann::json runOpBench(const EngineOptions& options, const OpBenchArgs& args);

}  // namespace spar::bench
