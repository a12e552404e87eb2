// Rotary position embedding (RoPE) of q and k inside a fused qkv tensor, on shaders/rope.comp.
#pragma once
#include <cstdint>

#include "engine/recorder.h"

namespace spar {

// qkv: [B, N, C] f32 with q heads at columns [0, D) and k heads at [D, 2D), D = heads * headDim,
// 2D <= C (a fused [B, N, 3D] tensor; v is not touched). Rotates, in place, every q and k head
// of the tokens t >= prefix of each sequence (the first `prefix` tokens, e.g. DINOv3's cls and
// storage tokens, stay as they are):
//   x' = x * cos[t - prefix] + rotate_half(x) * sin[t - prefix],  rotate_half([a, b]) = [-b, a]
// with a, b the halves of the head. sin, cos: [N - prefix, headDim] f32, as the caller built
// them (position tables depend only on the token grid: build them once, in double, on the host).
// headDim must be even.
void rope(Recorder& rec, const Tensor& qkv, int64_t heads, int64_t headDim, int64_t prefix, const Tensor& sin,
          const Tensor& cos);

}  // namespace spar
