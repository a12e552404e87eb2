// Health check of a tensor on the device (shaders/count_nonfinite.comp): counts[slot] += how
// many of its values are NaN or infinite. One read of the tensor, no host transfer; the
// caller reads the small counter tensor once for many checks.
#pragma once
#include <cstdint>

#include "engine/recorder.h"

namespace spar {

// x: F32, any shape; counts: I32 [slots] (zeroed by the caller), slot < slots.
void countNonFinite(Recorder& rec, const Tensor& x, const Tensor& counts, int64_t slot);

}  // namespace spar
