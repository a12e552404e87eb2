#version 450
// The device's arithmetic ceiling: independent multiply-add chains on registers, no memory
// traffic in the loop, so spar-bench can say how far each kernel is from what the device (or
// a CPU driver's generated code) can do at all. Host side: tools/spar_bench/bench_cases.cpp (peak_f32).
//! variant peak_flops
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const int CHAINS = 8;       // independent accumulators per invocation
layout(constant_id = 4) const bool USE_FMA = true;  // fma() or a * b + c
layout(constant_id = 5) const int UNROLL = 1;       // loop trips' bodies written out per trip

layout(binding = 0) writeonly buffer Y { float y[]; };
layout(push_constant) uniform Push { int iterations; float a, b; } p;

void main() {
  float acc[CHAINS];
  [[unroll]] for (int i = 0; i < CHAINS; ++i) acc[i] = float(gl_GlobalInvocationID.x + i);
  for (int it = 0; it < p.iterations; it += UNROLL) {
    [[unroll]] for (int u = 0; u < UNROLL; ++u)
    [[unroll]] for (int i = 0; i < CHAINS; ++i) acc[i] = USE_FMA ? fma(acc[i], p.a, p.b) : acc[i] * p.a + p.b;
  }
  float s = 0.0;
  [[unroll]] for (int i = 0; i < CHAINS; ++i) s += acc[i];
  y[gl_GlobalInvocationID.x] = s;
}
