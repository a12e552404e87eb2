// spar-bench's CPU peer: each case's op, shape and float32 data run by numpy / PyTorch on this
// machine's cores in the same spar-bench run (scripts/compare/bench_peer.py says what runs
// which op), so a case's time reads as a multiple of what a CPU library does with it. The
// script runs with OPENBLAS_CORETYPE and OPENBLAS_L2_SIZE removed from its environment: they
// hold OpenBLAS to narrower kernels than the CPU has (docs/benchmarks.md).
#pragma once
#include <optional>
#include <string>
#include <vector>

#include "tools/spar_bench/bench_cases.h"

namespace spar::bench {

struct PeerTimes {
  std::string peer;                        // what ran, e.g. "numpy 1.24.2 (OpenBLAS); ..."
  std::vector<std::optional<double>> ms;   // per case: median ms of `repeats` runs; none without a peer
};

// Times the peer of every case that has one (BenchCase::peer), `repeats` runs after a warm-up.
// Throws Error, with the command, where Python or the script is missing or fails.
PeerTimes runPeer(const std::vector<BenchCase>& cases, int repeats);

}  // namespace spar::bench
