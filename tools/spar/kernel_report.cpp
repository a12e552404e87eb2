#include "tools/spar/kernel_report.h"

namespace spar::cli {

nlohmann::ordered_json kernelReportJson(const KernelReport& r) {
  nlohmann::ordered_json list = nlohmann::ordered_json::array();
  for (const KernelStats& s : r.kernels) {
    nlohmann::ordered_json e = {{"name", s.name},
                                {"texel_formats", s.texelFormats},
                                {"create_ms", s.createMs},
                                {"builds", s.builds},
                                {"compiles", s.compiles},
                                {"build_ms", s.buildMs},
                                {"dispatches", s.dispatches},
                                // distinct texel binding states the driver saw: 1 keeps a CPU
                                // driver at one compiled variant
                                {"texel_states", s.texelStates},
                                {"gpu_ms", s.gpuMs}};
    if (!s.rebuildCauses.empty()) {
      nlohmann::ordered_json causes = nlohmann::ordered_json::object();
      for (const auto& [cause, count] : s.rebuildCauses) causes[cause] = count;
      e["rebuild_causes"] = causes;
    }
    list.push_back(e);
  }
  return {{"plan", r.plan},  // the kernel family per op and why (--list-kernels)
          {"pipelines", r.pipelines},
          {"create_ms", r.createMs},  // summed over pipelines (they are created several at a time)
          {"builds", r.builds},       // driver builds at dispatch: compiles, or reloads from its cache
          {"compiles", r.compiles},   // builds long enough to be compiles (an estimate)
          {"rebuilds", r.rebuilds},   // builds beyond the first of a pipeline (0 when each is built once)
          {"build_ms", r.buildMs},
          {"dispatches", r.dispatches},
          {"compute_ms", r.computeMs},
          {"list", list}};
}

}  // namespace spar::cli
