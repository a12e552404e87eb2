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

// What attention does to the q and k heads first (both optional): each head RMS-normed (SPAR's
// q_norm / k_norm: x / sqrt(mean(x^2) + eps) * weight), then rotated by RoPE (DINOv3: rope()'s
// tables and prefix, engine/ops/rope.h). The GPU and llvmpipe kernels do it as they read the
// heads (shaders/attention_prep.glsl): one dispatch instead of three. Where the kernel cannot
// (RoPE on heads whose channels do not pair up, too few bindings: preparesInKernel) rmsNormHeads
// and rope() run first, in place. Either way q and k must be one fused [B, N, C] qkv tensor, q at column 0 and k at
// heads * headDim, and the values attention sees are those the in-place ops would leave.
struct QkPrep {
  Tensor normWeight;  // f32 [2, headDim]: q_norm's weight, then k_norm's; undefined: no norm
  float normEps = 1e-6f;
  Tensor ropeSin, ropeCos;  // f32 [N - ropePrefix, headDim]; undefined: no RoPE
  int64_t ropePrefix = 0;
  bool any() const { return normWeight.defined() || ropeSin.defined(); }
};

// Whether attention() prepares fp32 q and k heads of headDim inside its kernel on this device,
// one dispatch (else rmsNormHeads and rope() run first): bindings the device allows, RoPE
// channels that pair up in the kernel chosen (coopMat: the fp16 layer's cooperative matrices).
bool preparesInKernel(Engine& engine, int headDim, const QkPrep& prep, bool coopMat = false);

// The shared memory of attention_flash.comp: q rows of a workgroup, k and v rows of a block,
// the block's probabilities and, combining rows through shared memory, partialLanes floats a query.
uint64_t attentionFlashSharedBytes(int queries, int keys, int partialLanes, int headDim);

// out = softmax(q k^T * scale) v per head (scale 0 means 1/sqrt(headDim)); causal masks
// keys after the query's own position. q, k, v may be f32 or f16; out f32 or f16.
// fp16Layer: the caller's layer computes in fp16 (its weights are fp16): where the device has
// cooperative matrices (KernelPlan::attentionF16) q, k and v are then rounded to fp16 for
// them, as fp16 inputs always may be; otherwise the arithmetic is fp32.
void attention(Recorder& rec, const HeadsView& q, const HeadsView& k, const HeadsView& v, const HeadsView& out,
               int heads, int headDim, bool causal = false, float scale = 0.0f, bool fp16Layer = false,
               const QkPrep& prep = {});

}  // namespace spar
