// Reductions along "lines" (rows, heads, channel columns), shared by shaders/norm.comp and
// shaders/reduce_channels.comp; included after their local_size layout. Host side of the
// workgroup shape: lineGroupFor() in engine/ops/dispatch_helpers.h.
//
// Workgroup (LX, LY, 1); workgroups may form a 2-D grid (linear index y * gridX + x).
//   SPLIT_LINES: the LX invocations along x share one line (unit u goes to invocation
//     u % LX) and a workgroup takes LY lines: long contiguous lines.
//   otherwise: every invocation owns a whole line and a workgroup takes LX * LY consecutive
//     lines: short lines, or strided lines whose neighbours are adjacent in memory (NCHW
//     channels), so the invocations of a SIMD group read adjacent addresses.
// Partial results meet in shared memory and are combined in lane order, so every invocation
// of a line gets the same value. Every invocation must call the reductions (they contain
// barriers): invocations past the last line take part with neutral values.
// SUBGROUP (variants *_sg, GPUs with subgroup arithmetic; the host gives such a workgroup one
// split line, LY = 1, so every subgroup lies inside the line whatever the device's mapping of
// invocations to subgroups): each subgroup reduces its lanes with one subgroup operation and
// the subgroups' results meet in shared memory, combined in subgroup order.

layout(constant_id = 3) const bool SPLIT_LINES = true;
// VEC4: a line is read in units of a vec4 (4 consecutive values; line length, strides and
// offsets are multiples of 4), which llvmpipe loads for about the cost of one float.
// Otherwise a unit is one value, carried in the .x component; the helpers below ignore the
// other components then.
layout(constant_id = 4) const bool VEC4 = false;

uint unitWidth() { return VEC4 ? 4u : 1u; }
float unitSum(vec4 v) { return VEC4 ? (v.x + v.y) + (v.z + v.w) : v.x; }
float unitMax(vec4 v) { return VEC4 ? max(max(v.x, v.y), max(v.z, v.w)) : v.x; }

uint lineLanes() { return SPLIT_LINES ? gl_WorkGroupSize.x : 1u; }
uint lineLane() { return SPLIT_LINES ? gl_LocalInvocationID.x : 0u; }

uint lineIndex() {
  const uint group = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
  const uint row = group * gl_WorkGroupSize.y + gl_LocalInvocationID.y;
  return SPLIT_LINES ? row : row * gl_WorkGroupSize.x + gl_LocalInvocationID.x;
}

shared float lineShared[gl_WorkGroupSize.x * gl_WorkGroupSize.y];

#ifndef SUBGROUP
#define SUBGROUP 0
#endif
#if SUBGROUP
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_basic : require
// op: 0 sum, 1 max.
float subgroupLineReduce(float v, int op) {
  const float s = op == 0 ? subgroupAdd(v) : subgroupMax(v);
  if (subgroupElect()) lineShared[gl_SubgroupID] = s;
  barrier();
  float r = lineShared[0];
  for (uint j = 1; j < gl_NumSubgroups; ++j) r = op == 0 ? r + lineShared[j] : max(r, lineShared[j]);
  barrier();
  return r;
}
#endif

float lineSum(float v) {
  if (!SPLIT_LINES) return v;
#if SUBGROUP
  return subgroupLineReduce(v, 0);
#endif
  const uint row = gl_LocalInvocationID.y * gl_WorkGroupSize.x;
  lineShared[row + gl_LocalInvocationID.x] = v;
  barrier();
  float s = lineShared[row];
  for (uint j = 1; j < gl_WorkGroupSize.x; ++j) s += lineShared[row + j];
  barrier();
  return s;
}

float lineMax(float v) {
  if (!SPLIT_LINES) return v;
#if SUBGROUP
  return subgroupLineReduce(v, 1);
#endif
  const uint row = gl_LocalInvocationID.y * gl_WorkGroupSize.x;
  lineShared[row + gl_LocalInvocationID.x] = v;
  barrier();
  float m = lineShared[row];
  for (uint j = 1; j < gl_WorkGroupSize.x; ++j) m = max(m, lineShared[row + j]);
  barrier();
  return m;
}
