// The benchmark's cases: each sets up its inputs, records its op, and measures its
// result against a float64 CPU reference (on sampled rows where the full one is slow).
#pragma once
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "engine/internal_ops.h"

namespace spar::bench {

struct BenchCase {
  std::string name;     // op and precision, e.g. "gemm_f32"
  std::string shape;    // human-readable shape
  double flops = 0;     // work per run (0: report GB/s from bytes instead)
  double bytes = 0;     // memory traffic per run (for memory-bound ops)
  std::function<void(Recorder&)> record;  // records one run
  std::function<double()> nmse;           // error of the last run's output vs float64
  // The same op for the CPU peer (tools/spar_bench/bench_peer.h; scripts/compare/bench_peer.py): {"op":
  // "gemm", "m", "k", "n"}, {"op": "attention", ...}, ...; null where there is none.
  nlohmann::json peer;
};

// Every case of the benchmark, with inputs uploaded. `only` filters by name substring (before any
// input is made); `large` adds the 4096^3 GEMMs (GPUs; minutes on a CPU device).
std::vector<BenchCase> makeCases(Engine& engine, const std::string& only, bool large);

}  // namespace spar::bench
