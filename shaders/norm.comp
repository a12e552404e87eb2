#version 450
// LayerNorm and RMSNorm over lines of a 2-D tensor. Host side: engine/ops/norm.cpp.
// Line (r, h) is the DH values at columns col0 + h * DH of row r (row stride given), so a
// plain [rows, D] norm is one head of D at column 0, and per-head RMSNorm of the q or k part
// of a fused qkv tensor [T, 3D] runs in place on heads at column 0 or D, or on both at once: 2H
// heads at column 0, each weight row shared by H of them (weightHeads).
//   layernorm: y = (x - mean) / sqrt(var + eps) * weight + bias
//   rmsnorm:   y = x / sqrt(mean(x^2) + eps) * weight
// LayerNorm numerics: values are shifted by the line's first value before anything is
// summed (exact for values within a factor of two of it), then mean and variance come from
// two passes in fp32. Rows with mean 1e4 and variance 1e-6 keep full accuracy, and constant
// rows give exactly 0 before weight and bias. RMSNorm of an all-zero line gives 0.
//! variant layernorm NORM=0 IN_PLACE=0
//! variant layernorm_inplace NORM=0 IN_PLACE=1
//! variant rmsnorm NORM=1 IN_PLACE=0
//! variant rmsnorm_inplace NORM=1 IN_PLACE=1
//! variant layernorm_sg NORM=0 IN_PLACE=0 SUBGROUP=1
//! variant layernorm_inplace_sg NORM=0 IN_PLACE=1 SUBGROUP=1
//! variant rmsnorm_sg NORM=1 IN_PLACE=0 SUBGROUP=1
//! variant rmsnorm_inplace_sg NORM=1 IN_PLACE=1 SUBGROUP=1
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

#define NORM_LAYER 0
#define NORM_RMS 1

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
#include "line_reduce.glsl"  // constant_id 3: SPLIT_LINES, 4: VEC4
layout(constant_id = 5) const bool HAS_WEIGHT = true;
layout(constant_id = 6) const bool HAS_BIAS = false;  // layernorm only

// Every buffer holds f32 values, declared as vec4s for VEC4 loads.
#if IN_PLACE
layout(binding = 0) buffer XY { vec4 x[]; };
#define Y x
#define BINDING_W 1
#else
layout(binding = 0) readonly buffer X { vec4 x[]; };
layout(binding = 1) writeonly buffer Yb { vec4 y[]; };
#define Y y
#define BINDING_W 2
#endif
// Bound to x when absent (HAS_WEIGHT / HAS_BIAS false).
layout(binding = BINDING_W) readonly buffer Wb { vec4 weight[]; };
#if NORM == NORM_LAYER
layout(binding = BINDING_W + 1) readonly buffer Bb { vec4 bias[]; };
#endif

layout(push_constant) uniform Push {
  uint rows, heads, dh;
  uint xStride, xCol0;  // row stride and column of head 0 in x (values)
  uint yStride, yCol0;  // the same in y (equal to x's in place)
  float eps;
  uint weightHeads;     // heads sharing a row of the weight, [heads / weightHeads, DH] (0: one row for all)
} p;

// The unit (vec4 or one value in .x) starting at value e.
vec4 loadX(uint e) { return VEC4 ? x[e >> 2] : vec4(x[e >> 2][e & 3u]); }
vec4 loadWeight(uint e) { return VEC4 ? weight[e >> 2] : vec4(weight[e >> 2][e & 3u]); }
#if NORM == NORM_LAYER
vec4 loadBias(uint e) { return VEC4 ? bias[e >> 2] : vec4(bias[e >> 2][e & 3u]); }
#endif
void storeY(uint e, vec4 v) {
  if (VEC4) Y[e >> 2] = v;
  else Y[e >> 2][e & 3u] = v.x;
}

void main() {
  const uint line = lineIndex(), lane = lineLane(), lanes = lineLanes(), w = unitWidth();
  const bool live = line < p.rows * p.heads;
  const uint r = live ? line / p.heads : 0u, h = live ? line % p.heads : 0u;
  const uint xb = r * p.xStride + p.xCol0 + h * p.dh;
  const uint yb = r * p.yStride + p.yCol0 + h * p.dh;
  const uint units = live ? p.dh / w : 0u;  // lines past the end only join the reductions
  const uint wb = p.weightHeads > 0u ? (h / p.weightHeads) * p.dh : 0u;  // the head's weight row

#if NORM == NORM_LAYER
  const float shift = live ? loadX(xb).x : 0.0;
  float s = 0.0;
  for (uint u = lane; u < units; u += lanes) s += unitSum(loadX(xb + u * w) - shift);
  const float mean = lineSum(s) / float(p.dh);  // of the shifted values
  float q = 0.0;
  for (uint u = lane; u < units; u += lanes) {
    const vec4 d = (loadX(xb + u * w) - shift) - mean;
    q += unitSum(d * d);
  }
  const float rstd = 1.0 / sqrt(lineSum(q) / float(p.dh) + p.eps);
  for (uint u = lane; u < units; u += lanes) {
    vec4 v = ((loadX(xb + u * w) - shift) - mean) * rstd;
    if (HAS_WEIGHT) v *= loadWeight(wb + u * w);
    if (HAS_BIAS) v += loadBias(u * w);
    storeY(yb + u * w, v);
  }
#else
  float q = 0.0;
  for (uint u = lane; u < units; u += lanes) {
    const vec4 v = loadX(xb + u * w);
    q += unitSum(v * v);
  }
  const float ms = lineSum(q) / float(p.dh) + p.eps;
  const float rstd = ms > 0.0 ? 1.0 / sqrt(ms) : 0.0;  // eps = 0 and an all-zero line: 0, not NaN
  for (uint u = lane; u < units; u += lanes) {
    vec4 v = loadX(xb + u * w) * rstd;
    if (HAS_WEIGHT) v *= loadWeight(wb + u * w);
    storeY(yb + u * w, v);
  }
#endif
}
