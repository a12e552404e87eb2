#version 450
// counts[slot] += the number of NaN or infinite values among x[0 .. n): the engine's cheap
// health check of a stage's output (a NaN weight or an overflow turns whole images black
// downstream; this says where it started). Host side: engine/ops/count_nonfinite.cpp.
// Tested on the bits (exponent all ones), which no compiler's float model can fold away.
//! variant count_nonfinite
layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;

layout(binding = 0) readonly buffer X { uint x[]; };
layout(binding = 1) buffer Counts { uint counts[]; };

layout(push_constant) uniform Push {
  uint n;     // values of this chunk
  uint slot;  // which counter
} p;

void main() {
  const uint group = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;  // 2-D grid, x fastest
  const uint base = (group * gl_WorkGroupSize.x + gl_LocalInvocationID.x) * 4u;
  uint bad = 0u;
  for (uint k = 0u; k < 4u; ++k) {
    const uint i = base + k;
    if (i < p.n && (x[i] & 0x7f800000u) == 0x7f800000u) bad += 1u;
  }
  if (bad != 0u) atomicAdd(counts[p.slot], bad);
}
