#include "model/nonfinite_watch.h"

#include <algorithm>
#include <cstdint>

#include "spar/error.h"
#include "engine/ops/count_nonfinite.h"

namespace spar {

NonFiniteWatch::NonFiniteWatch(Engine& engine) : engine_(engine), counts_(engine.tensor({kSlots}, DType::I32)) {
  reset();
}

void NonFiniteWatch::reset() {
  const std::vector<int32_t> zeros(kSlots, 0);
  engine_.write(counts_, zeros.data(), zeros.size() * sizeof(int32_t));
  stages_.clear();
}

void NonFiniteWatch::watch(Recorder& rec, const std::string& stage, const Tensor& t) {
  if (!t.defined()) return;
  auto it = std::find(stages_.begin(), stages_.end(), stage);
  if (it == stages_.end()) {
    if (int64_t(stages_.size()) == kSlots) throw Error("NonFiniteWatch: more than 32 stages in one run");
    stages_.push_back(stage);
    it = stages_.end() - 1;
  }
  countNonFinite(rec, t, counts_, int64_t(it - stages_.begin()));
}

void NonFiniteWatch::check(const std::string& what) {
  if (stages_.empty()) return;
  std::vector<int32_t> counts(kSlots);
  engine_.read(counts_, counts.data(), counts.size() * sizeof(int32_t));
  for (size_t s = 0; s < stages_.size(); ++s)
    if (counts[s] != 0)
      throw Error(what + ": stage " + stages_[s] + " produced " + std::to_string(uint32_t(counts[s])) +
                  " non-finite values (NaN or infinity): the model's weights are damaged, or too large for this "
                  "input");
}

}  // namespace spar
