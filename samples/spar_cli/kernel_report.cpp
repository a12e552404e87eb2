#include "samples/spar_cli/kernel_report.h"

namespace spar::cli {

nlohmann::ordered_json kernelReport(const Engine& engine) {
  const PipelineCache& cache = const_cast<Engine&>(engine).pipelines();
  const PipelineTotals t = cache.totals();
  nlohmann::ordered_json list = nlohmann::ordered_json::array();
  for (const Pipeline* p : cache.pipelines()) {
    const PipelineStats& s = p->stats;
    nlohmann::ordered_json e = {{"name", p->name},
                                {"texel_formats", p->signature},
                                {"create_ms", s.createMs},
                                {"builds", s.builds},
                                {"compiles", s.compiles},
                                {"build_ms", s.buildMs},
                                {"dispatches", s.dispatches},
                                // distinct texel binding states the driver saw: 1 keeps a CPU
                                // driver at one compiled variant
                                {"texel_states", s.texelStates.size()},
                                {"gpu_ms", s.gpuMs}};
    if (s.rebuildCount() > 0) {
      nlohmann::ordered_json causes = nlohmann::ordered_json::object();
      for (int c = 1; c < 4; ++c)
        if (s.rebuilds[c]) causes[buildCauseName(static_cast<BuildCause>(c))] = s.rebuilds[c];
      e["rebuild_causes"] = causes;
    }
    list.push_back(e);
  }
  Engine& e = const_cast<Engine&>(engine);
  return {{"plan", describePlan(e.plan(), e.caps())},  // the kernel family per op and why (--list-kernels)
          {"pipelines", t.pipelines},
          {"create_ms", t.createMs},  // summed over pipelines (they are created several at a time)
          {"builds", t.builds},       // driver builds at dispatch: compiles, or reloads from its cache
          {"compiles", t.compiles},   // builds long enough to be compiles (an estimate, see pipeline_stats.h)
          {"rebuilds", t.rebuilds},   // builds beyond the first of a pipeline (0 when each is built once)
          {"build_ms", t.buildMs},
          {"dispatches", t.dispatches},
          {"compute_ms", t.gpuMs},
          {"list", list}};
}

}  // namespace spar::cli
