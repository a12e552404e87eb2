#version 450
// Elementwise out = a (+ or *) b with b broadcast by repetition: value i of a meets
// b[((i + bPhase) / bInner) % bSize]. Same shapes: bInner 1, bSize n; a bias per column of
// [R, C]: bInner 1, bSize C; a value per channel of NCHW: bInner H * W, bSize C. bPhase is
// the index of the first value when the host splits a into chunks (a multiple of 4).
// In place: out is a. Host side: engine/ops/binary.cpp.
// Every invocation handles one vec4 of a (4 consecutive values); a tail of 1-3 values goes by
// component. B_MODE says how the 4 values of b are found:
//   0: one index each; 1: one value for all 4 (bInner % 4 == 0);
//   2: one vec4 of b (bInner == 1, bSize % 4 == 0).
//! variant binary_add OP=0 IN_PLACE=0
//! variant binary_add_inplace OP=0 IN_PLACE=1
//! variant binary_mul OP=1 IN_PLACE=0
//! variant binary_mul_inplace OP=1 IN_PLACE=1
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

#define OP_ADD 0
#define OP_MUL 1

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const int B_MODE = 0;

#if IN_PLACE
layout(binding = 0) buffer AO { vec4 a[]; };
layout(binding = 1) readonly buffer B { vec4 b[]; };
#define OUT a
#else
layout(binding = 0) readonly buffer A { vec4 a[]; };
layout(binding = 1) readonly buffer B { vec4 b[]; };
layout(binding = 2) writeonly buffer O { vec4 o[]; };
#define OUT o
#endif

layout(push_constant) uniform Push {
  uint n, bInner, bSize, bPhase;
} p;

float bAt(uint i) {
  const uint k = ((i + p.bPhase) / p.bInner) % p.bSize;
  return b[k >> 2][k & 3u];
}

vec4 combine(vec4 u, vec4 v) {
#if OP == OP_ADD
  return u + v;
#else
  return u * v;
#endif
}

void main() {
  const uint group = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;  // 2-D grid, x fastest
  const uint q = group * gl_WorkGroupSize.x + gl_LocalInvocationID.x;
  const uint i = 4u * q;
  if (i >= p.n) return;
  if (i + 4u <= p.n) {
    vec4 bv;
    if (B_MODE == 2) bv = b[((i + p.bPhase) % p.bSize) >> 2];
    else if (B_MODE == 1) bv = vec4(bAt(i));
    else bv = vec4(bAt(i), bAt(i + 1u), bAt(i + 2u), bAt(i + 3u));
    OUT[q] = combine(a[q], bv);
  } else {
    for (uint j = 0; i + j < p.n; ++j) OUT[q][j] = combine(vec4(a[q][j]), vec4(bAt(i + j))).x;
  }
}
