// What the engine compiled and ran (Context::kernelReport): the kernel family it chose per op
// on this device and why, and per pipeline what creating it cost, how often the driver built
// code for it at a dispatch, and its compute time. `spar render` writes it as report.json's
// "kernels"; docs/first-run-and-kernels.md explains the figures.
#pragma once
#include <cstdint>
#include <map>
#include <string>
#include <vector>

namespace spar {

struct KernelStats {
  std::string name;
  std::string texelFormats;  // the formats of its texel inputs, as the pipeline was specialized
  double createMs = 0;       // vkCreateComputePipelines
  uint64_t builds = 0;       // driver builds at a dispatch: compiles, or reloads from its cache
  uint64_t compiles = 0;     // builds long enough to be compiles (an estimate)
  double buildMs = 0;
  uint64_t dispatches = 0;
  uint64_t texelStates = 0;  // distinct texel binding states the driver saw (1 keeps a CPU driver at one variant)
  double gpuMs = 0;
  std::map<std::string, uint64_t> rebuildCauses;  // builds beyond the first, by cause
};

struct KernelReport {
  std::vector<std::string> plan;  // the kernel family per op and why (`spar-bench --list-kernels`)
  uint64_t pipelines = 0;
  double createMs = 0;            // summed over pipelines
  uint64_t builds = 0, compiles = 0;
  uint64_t rebuilds = 0;          // builds beyond the first of a pipeline
  double buildMs = 0;
  uint64_t dispatches = 0;
  double computeMs = 0;
  std::vector<KernelStats> kernels;  // in creation order
};

}  // namespace spar
