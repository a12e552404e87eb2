// Fused multi-head attention on shaders/attention.comp.
#pragma once
#include "engine/recorder.h"

namespace spar {

// Heads laid out as PyTorch's "(nh dh)" columns of a [B, N, C] tensor, starting at a
// column offset: a fused qkv tensor [B, N, 3D] gives q at column 0, k at D, v at 2D.
struct HeadsView {
  Tensor tensor;       // [B, N, C] or [N, C]
  int64_t column = 0;  // column of head 0, channel 0
};

// out = softmax(q k^T * scale) v per head (scale 0 means 1/sqrt(headDim)); causal masks
// keys after the query's own position. q, k, v may be f32 or f16; out f32 or f16.
// fp16Layer: the caller's layer computes in fp16 (its weights are fp16): where the device has
// cooperative matrices (KernelPlan::attentionF16) q, k and v are then rounded to fp16 for
// them, as fp16 inputs always may be; otherwise the arithmetic is fp32.
void attention(Recorder& rec, const HeadsView& q, const HeadsView& k, const HeadsView& v, const HeadsView& out,
               int heads, int headDim, bool causal = false, float scale = 0.0f, bool fp16Layer = false);

}  // namespace spar
