// What one process measured about each pipeline: creation time, how often the driver built
// machine code for it at a dispatch and why, and its compute time.
//
// Where the compile happens depends on the driver: GPU drivers compile in
// vkCreateComputePipelines (createMs); llvmpipe compiles at the first dispatch of each
// variant (a build). The Recorder, when profiling, precedes every dispatch with an empty
// dispatch of the same state (no workgroups): a driver that builds at dispatch does it
// there, so that stretch of the timeline is the build and the real dispatch is compute.
#pragma once
#include <cstdint>
#include <set>
#include <string>

namespace spar {

// An empty dispatch that takes longer than this built something (measured on lavapipe:
// an empty dispatch of a built variant takes ~0.01 ms, reloading a variant from Mesa's disk
// cache 1-10 ms, compiling one 30 ms to seconds).
constexpr double kDriverBuildThresholdMs = 0.5;
// A pipeline's later builds must take at least this long, and half its first one.
constexpr double kLaterBuildFloorMs = 2.0;
// A build this long is taken for a compile rather than a reload from the driver's cache (an
// estimate: the app cannot see which. On lavapipe here reloads took 1-15 ms, the smallest
// compile 30 ms on Mesa 22.3 and 200 ms on 25.0.7).
constexpr double kCompileThresholdMs = 20.0;

enum class BuildCause {
  FirstUse,       // the pipeline's first build
  NewTexelState,  // a texel binding state this pipeline had not seen (format, sizes)
  NewPushValues,  // push-constant values it had not seen: the driver specialises on them
  Repeat,         // state and values seen before: the driver evicted or did not keep the variant
};
const char* buildCauseName(BuildCause cause);

// One dispatch as the Recorder saw it.
struct DispatchObservation {
  double buildMs = 0;      // the empty dispatch before it
  double ms = 0;           // the dispatch itself
  std::string texelState;  // what a driver may key variants on (Recorder::texelState)
  std::string pushValues;  // the push-constant bytes
};

struct PipelineStats {
  double createMs = 0;  // vkCreateComputePipelines
  int builds = 0;       // driver builds seen at dispatches
  int compiles = 0;     // those of them long enough to be compiles (kCompileThresholdMs)
  double buildMs = 0;
  double firstBuildMs = 0;
  int rebuilds[4] = {0, 0, 0, 0};  // builds by BuildCause (FirstUse counts the first)
  int dispatches = 0;
  double gpuMs = 0;  // compute time of the dispatches
  std::set<std::string> texelStates, pushValues;  // seen at dispatches

  // Counts the dispatch; returns the cause when the driver built something for it.
  bool observe(const DispatchObservation& d, BuildCause* cause);
  int rebuildCount() const { return builds > 0 ? builds - 1 : 0; }
};

// Sums over every pipeline of an engine.
struct PipelineTotals {
  int pipelines = 0;
  double createMs = 0;
  int builds = 0;
  int compiles = 0;
  int rebuilds = 0;  // builds beyond one per pipeline
  double buildMs = 0;
  int dispatches = 0;
  double gpuMs = 0;
};

}  // namespace spar
