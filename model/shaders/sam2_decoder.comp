#version 450
// SAM2.1's prompt encoder and mask decoder glue (official sam/prompt_encoder.py,
// sam/mask_decoder.py; reference reference/spar_reference/sam2.py). Host side:
// model/sam2_mask_decoder.cpp.
//   sam2_mask_prompt    prob [H, W] -> logits [H, W]: 20 * (prob > 0.5) - 10 (SPAR's prompt)
//   sam2_dense_pe       gaussian [2, d/2] -> pe [side * side, d]: p = 2 pi ((2 (x + 0.5) / side
//                       - 1) g0 + (2 (y + 0.5) / side - 1) g1), channels [sin p, cos p]
//                       (PositionEmbeddingRandom; input-independent)
//   sam2_channels_first x [H * W, C] -> y [C, H, W]
//   sam2_chosen_mask    upscaled [N, c], hyper [3, c], iou [3] -> logits [N]: the product of the
//                       mask of the highest IoU (the first of equal ones) only
//   sam2_threshold      y = x > t ? 1 : 0 (t = a as float bits): the binary prompt (0.5) and
//                       the refined mask (logits > 0)
//   sam2_count_dynamic  probs [V, H * W] -> counts [V] (i32, zeroed by the host): how many
//                       P(dynamic) > 0.5, SPAR's skip rule; 64 pixels per invocation, one atomic
// One invocation per output value.
//! variant sam2_mask_prompt MODE=0
//! variant sam2_dense_pe MODE=1
//! variant sam2_channels_first MODE=2
//! variant sam2_chosen_mask MODE=3
//! variant sam2_threshold MODE=4
//! variant sam2_count_dynamic MODE=5
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;

layout(binding = 0) readonly buffer In { float xin[]; };
#if MODE == 5
layout(binding = 1) buffer Counts { int counts[]; };
#else
layout(binding = 1) writeonly buffer Out { float yout[]; };
#endif
#if MODE == 3
layout(binding = 2) readonly buffer Hyper { float hyper[]; };
layout(binding = 3) readonly buffer Iou { float iou[]; };
#endif

layout(push_constant) uniform Push {
  uint total;  // output values
  uint a, b;   // dense_pe: side, d/2; channels_first: H * W, C; chosen_mask: c
} p;

void main() {
  const uint group = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;  // 2-D grid, x fastest
  const uint i = group * gl_WorkGroupSize.x + gl_LocalInvocationID.x;
  if (i >= p.total) return;
#if MODE == 0
  yout[i] = xin[i] > 0.5 ? 10.0 : -10.0;
#elif MODE == 1
  const uint side = p.a, half_d = p.b, k = i % (2u * half_d), cell = i / (2u * half_d);
  const uint kk = k % half_d;
  const float x = 2.0 * ((float(cell % side) + 0.5) / float(side)) - 1.0;
  const float y = 2.0 * ((float(cell / side) + 0.5) / float(side)) - 1.0;
  const float arg = 6.283185307179586 * (x * xin[kk] + y * xin[half_d + kk]);
  yout[i] = k < half_d ? sin(arg) : cos(arg);
#elif MODE == 2
  const uint hw = p.a, c = i / hw, pix = i % hw;
  yout[i] = xin[pix * p.b + c];
#elif MODE == 4
  yout[i] = xin[i] > uintBitsToFloat(p.a) ? 1.0 : 0.0;
#elif MODE == 5
  // i: one run of 64 pixels of one view; a = H * W, b = runs per view
  const uint v = i / p.b, start = (i % p.b) * 64u, end = min(start + 64u, p.a);
  int n = 0;
  for (uint j = start; j < end; ++j) n += xin[v * p.a + j] > 0.5 ? 1 : 0;
  if (n > 0) atomicAdd(counts[v], n);
#else
  const uint c = p.b;
  uint best = 0u;
  for (uint m = 1u; m < 3u; ++m)
    if (iou[m] > iou[best]) best = m;
  float acc = 0.0;
  for (uint j = 0u; j < c; ++j) acc += xin[i * c + j] * hyper[best * c + j];
  yout[i] = acc;
#endif
}
