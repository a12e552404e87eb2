// Some views of a sequence as a tensor of their own, copied on the device (the inputs' images
// for LSeg, the views SAM2.1 refines).
#pragma once
#include <cstdint>
#include <vector>

#include "engine/recorder.h"
#include "engine/tensor.h"

namespace spar::stages {

// The views `positions` of `all` [V, ...] whose views hold `perView` values each, as a tensor
// [positions.size(), viewShape...].
Tensor selectViews(Recorder& rec, const Tensor& all, const std::vector<int64_t>& positions, int64_t perView,
                   const Shape& viewShape);

}  // namespace spar::stages
