// Where a NaN or infinity first appeared in a run of the pipeline: each stage's output is
// counted on the device (engine/ops/count_nonfinite.h) into its own slot of one small counter
// tensor, and the host reads that tensor once at the end of encode() / render(). A damaged
// weight (a flipped byte that is still finite, 3e38) or an overflow then becomes a one-line
// error naming the first stage with non-finite values, instead of a black image.
#pragma once
#include <string>
#include <vector>

#include "engine/engine.h"
#include "engine/recorder.h"

namespace spar {

class NonFiniteWatch {
 public:
  explicit NonFiniteWatch(Engine& engine);

  // Starts a new run: every count back to zero, no stage watched.
  void reset();
  // Counts t's non-finite values (F32 tensors) under the stage's name; stages in run order.
  void watch(Recorder& rec, const std::string& stage, const Tensor& t);
  // After the recorders ran: throws spar::Error naming the first stage whose outputs held a
  // NaN or infinity (and how many), `what` saying what was being computed.
  void check(const std::string& what);

  // Its device counters, one a watched tensor (the memory estimate counts them).
  static constexpr int64_t kSlots = 32;

 private:
  Engine& engine_;
  Tensor counts_;
  std::vector<std::string> stages_;  // slot -> stage
};

}  // namespace spar
