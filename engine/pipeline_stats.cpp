#include "engine/pipeline_stats.h"

#include <algorithm>

namespace spar {

const char* buildCauseName(BuildCause cause) {
  switch (cause) {
    case BuildCause::FirstUse: return "first use";
    case BuildCause::NewTexelState: return "new texel binding state";
    case BuildCause::NewPushValues: return "new push-constant values";
    case BuildCause::Repeat: return "repeat (evicted or not kept by the driver)";
  }
  return "?";
}

bool PipelineStats::observe(const DispatchObservation& d, BuildCause* cause) {
  const bool newState = texelStates.insert(d.texelState).second;
  const bool newPush = pushValues.insert(d.pushValues).second;
  ++dispatches;
  gpuMs += d.ms;
  if (d.buildMs < kDriverBuildThresholdMs) return false;
  // A later build takes about as long as the first one (a compile, or a reload from the
  // driver's cache); a much shorter stretch, or one under kLaterBuildFloorMs after a first
  // build that was itself a reload of about a millisecond, is the thread being preempted.
  if (builds > 0 && d.buildMs < std::max(kLaterBuildFloorMs, 0.5 * firstBuildMs)) return false;
  if (builds == 0) firstBuildMs = d.buildMs;
  const BuildCause c = builds == 0 ? BuildCause::FirstUse
                       : newState  ? BuildCause::NewTexelState
                       : newPush   ? BuildCause::NewPushValues
                                   : BuildCause::Repeat;
  ++builds;
  if (d.buildMs >= kCompileThresholdMs) ++compiles;
  buildMs += d.buildMs;
  ++rebuilds[static_cast<int>(c)];
  if (cause) *cause = c;
  return true;
}

}  // namespace spar
