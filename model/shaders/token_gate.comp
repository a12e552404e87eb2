#version 450
// SPAR's input-token masking (reference/spar_reference/spar.py SPAR.gate, the official
// _apply_configurable_input_masking). Host side: model/gating.cpp.
//
// tokens [T, D], dyn [T] = P(dynamic) average-pooled over each token's patch, code
// [perView + 1, D] (2D sin-cos code of the patch, the last row mask_token) -> out [T, D]:
//   mode 0 soft_with_pe:  out = tok * (1 - p) + (mask + code[t % perView]) * p
//   mode 1 zero_out:      out = tok * (1 - p)
// The pooled dynamic probability p is the mask weight itself: the official code pools
// s = 1 - P and forms 1 - s again, which cancels in float when P is near 0.01.
//! variant token_gate
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;

layout(binding = 0) readonly buffer Tokens { float tokens[]; };
layout(binding = 1) readonly buffer Dyn { float dyn[]; };
layout(binding = 2) readonly buffer Code { float code[]; };
layout(binding = 3) writeonly buffer Out { float outv[]; };

layout(push_constant) uniform Push {
  uint tokens, dim, perView, mode;
} p;

void main() {
  const uint group = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
  const uint i = group * gl_WorkGroupSize.x + gl_LocalInvocationID.x;
  if (i >= p.tokens * p.dim) return;
  const uint t = i / p.dim, c = i % p.dim;
  const float pd = dyn[t];
  const float kept = tokens[i] * (1.0 - pd);
  if (p.mode == 0u) {
    outv[i] = fma(code[p.perView * p.dim + c] + code[(t % p.perView) * p.dim + c], pd, kept);
  } else {
    outv[i] = kept;
  }
}
