#include "tools/spar_bench/op_bench.h"

#include <algorithm>
#include <cstdio>

#include "spar/error.h"
#include "tools/spar_bench/bench_cases.h"
#include "tools/spar_bench/bench_peer.h"

namespace spar::bench {
namespace {

// The CPU peer's times beside the engine's (report["ops"] in case order): "peer_ms" and
// "vs_peer", the engine's speed as a multiple of the peer's (above 1: the engine is faster).
void addPeerTimes(const std::vector<BenchCase>& cases, int repeats, nlohmann::json& report, bool json) {
  const PeerTimes peer = runPeer(cases, repeats);
  report["peer"] = peer.peer;
  if (!json) std::printf("\nCPU peer: %s\n%-15s %-30s %10s %10s %10s\n", peer.peer.c_str(), "op", "shape", "ms",
                         "peer ms", "x peer");
  for (size_t i = 0; i < cases.size(); ++i) {
    nlohmann::json& op = report["ops"][i];
    if (!peer.ms[i]) {
      op["peer_ms"] = op["vs_peer"] = nullptr;
      continue;
    }
    const double ms = op["ms"].get<double>(), ratio = *peer.ms[i] / ms;
    op["peer_ms"] = *peer.ms[i];
    op["vs_peer"] = ratio;
    if (!json)
      std::printf("%-15s %-30s %10.2f %10.2f %10.2f\n", cases[i].name.c_str(), cases[i].shape.c_str(), ms, *peer.ms[i],
                  ratio);
  }
}

// One case: a first run (pipeline creation, where GPU drivers compile, and the driver's build at
// the first dispatch, llvmpipe's JIT, each measured apart from the compute), then the timed runs.
nlohmann::json timeCase(Engine& engine, BenchCase& c, int repeats, bool json) {
  Recorder rec(engine, /*profile=*/true);
  const double createdBefore = engine.pipelines().totals().createMs;
  c.record(rec);
  rec.run();
  const double createMs = engine.pipelines().totals().createMs - createdBefore;
  const double buildMs = rec.totalBuildMs();
  std::vector<double> ms;
  for (int r = 0; r < repeats; ++r) {
    c.record(rec);
    rec.run();
    ms.push_back(rec.totalMs());
  }
  std::sort(ms.begin(), ms.end());
  const double median = ms[ms.size() / 2];
  const double nmse = c.nmse();
  const double rate = c.flops > 0 ? c.flops / (median * 1e6) : c.bytes / (median * 1e6);
  nlohmann::json op = {{"name", c.name}, {"shape", c.shape},       {"ms", median},
                       {"nmse", nmse},   {"create_ms", createMs}, {"build_ms", buildMs}};
  // Memory-bound ops count bytes, not flops: "gflops" is null and "gbps" says their rate.
  if (c.flops > 0) {
    op["gflops"] = rate;
  } else {
    op["gflops"] = nullptr;
    op["gbps"] = rate;
  }
  if (!json)
    std::printf("%-15s %-30s %10.2f %10.1f%s %12.3e %10.1f %10.1f\n", c.name.c_str(), c.shape.c_str(), median, rate,
                c.flops > 0 ? "" : " GB/s", nmse, createMs, buildMs);
  std::fflush(stdout);
  return op;
}

}  // namespace

nlohmann::json runOpBench(const EngineOptions& options, const OpBenchArgs& a) {
  Engine engine(options);
  auto cases = makeCases(engine, a.only, a.large || !engine.caps().isCpu());
  if (cases.empty()) throw Error("no benchmark case matches '" + a.only + "'");
  nlohmann::json report;
  report["device"] = engine.caps().name;
  report["kernels"] = describePlan(engine.plan(), engine.caps());
  report["ops"] = nlohmann::json::array();
  if (!a.json)
    std::printf("%-15s %-30s %10s %10s %12s %10s %10s\n", "op", "shape", "ms", "GFLOPS", "NMSE", "create ms", "build ms");
  for (auto& c : cases) report["ops"].push_back(timeCase(engine, c, a.repeats, a.json));
  if (a.peer) addPeerTimes(cases, a.repeats, report, a.json);
  return report;
}

}  // namespace spar::bench
