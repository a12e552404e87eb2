#version 450
// Elementwise unary ops, in place or out of place. Host side: engine/ops/unary.cpp.
//   gelu (exact erf), quick_gelu (x * sigmoid(1.702 x)), silu, sigmoid, relu: activate() of
//   common.glsl, finite and accurate for any finite x; scale: y = alpha * x + beta.
// Every invocation handles one vec4 (4 consecutive values): llvmpipe loads a vec4 whose
// address is not uniform for about the cost of a float. A tail of 1-3 values goes by component.
//! variant unary_gelu OP=ACT_GELU IN_PLACE=0
//! variant unary_gelu_inplace OP=ACT_GELU IN_PLACE=1
//! variant unary_quick_gelu OP=ACT_QUICK_GELU IN_PLACE=0
//! variant unary_quick_gelu_inplace OP=ACT_QUICK_GELU IN_PLACE=1
//! variant unary_silu OP=ACT_SILU IN_PLACE=0
//! variant unary_silu_inplace OP=ACT_SILU IN_PLACE=1
//! variant unary_sigmoid OP=ACT_SIGMOID IN_PLACE=0
//! variant unary_sigmoid_inplace OP=ACT_SIGMOID IN_PLACE=1
//! variant unary_relu OP=ACT_RELU IN_PLACE=0
//! variant unary_relu_inplace OP=ACT_RELU IN_PLACE=1
//! variant unary_scale OP=OP_SCALE IN_PLACE=0
//! variant unary_scale_inplace OP=OP_SCALE IN_PLACE=1
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

#define OP_SCALE 100

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;

#if IN_PLACE
layout(binding = 0) buffer XY { vec4 x[]; };
#define Y x
#else
layout(binding = 0) readonly buffer X { vec4 x[]; };
layout(binding = 1) writeonly buffer Yb { vec4 y[]; };
#define Y y
#endif

layout(push_constant) uniform Push {
  uint n;             // values (not vec4s)
  float alpha, beta;  // scale
} p;

float f(float v) {
#if OP == OP_SCALE
  return fma(p.alpha, v, p.beta);
#else
  return activate(v, OP);
#endif
}

void main() {
  const uint group = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;  // 2-D grid, x fastest
  const uint q = group * gl_WorkGroupSize.x + gl_LocalInvocationID.x;
  const uint i = 4u * q;
  if (i >= p.n) return;
  if (i + 4u <= p.n) {
    const vec4 v = x[q];
    Y[q] = vec4(f(v.x), f(v.y), f(v.z), f(v.w));
  } else {
    for (uint j = 0; i + j < p.n; ++j) Y[q][j] = f(x[q][j]);
  }
}
