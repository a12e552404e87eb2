#version 450
// Softmax, L2 normalization and argmax along the channel axis of a tensor viewed as
// [outer, C, inner]: line (o, i) is the C values at o * C * inner + c * inner + i. Softmax
// over the last dimension is inner = 1; argmax or L2 over NCHW channels is outer = N,
// inner = H * W. Host side: engine/ops/reduce_channels.cpp.
//   softmax:     y = exp(x - max) / sum(exp(x - max)), online per invocation (running max
//                starts at -FLT_MAX, not -inf); a line with nothing above -inf gives zeros
//   l2normalize: y = x / max(||x||, eps) (torch.nn.functional.normalize); the norm is taken
//                as 2^e * ||x * 2^-e|| with max |x| near 2^e, so huge values do not overflow
//   argmax:      first index of the maximum as int32; NaN counts as the maximum (torch)
// VEC4 (inner = 1 and C a multiple of 4): lines are read as vec4s.
//! variant softmax OP=0 IN_PLACE=0
//! variant softmax_inplace OP=0 IN_PLACE=1
//! variant l2normalize OP=1 IN_PLACE=0
//! variant l2normalize_inplace OP=1 IN_PLACE=1
//! variant argmax OP=2 IN_PLACE=0
//! variant softmax_sg OP=0 IN_PLACE=0 SUBGROUP=1
//! variant softmax_inplace_sg OP=0 IN_PLACE=1 SUBGROUP=1
//! variant l2normalize_sg OP=1 IN_PLACE=0 SUBGROUP=1
//! variant l2normalize_inplace_sg OP=1 IN_PLACE=1 SUBGROUP=1
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

#define OP_SOFTMAX 0
#define OP_L2 1
#define OP_ARGMAX 2
#define FLT_MAX 3.402823466e38

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
#include "line_reduce.glsl"  // constant_id 3: SPLIT_LINES, 4: VEC4

// f32 values declared as vec4s for VEC4 loads; argmax writes one int32 per line.
#if IN_PLACE
layout(binding = 0) buffer XY { vec4 x[]; };
#define Y x
#else
layout(binding = 0) readonly buffer X { vec4 x[]; };
#if OP == OP_ARGMAX
layout(binding = 1) writeonly buffer Yb { int y[]; };
#else
layout(binding = 1) writeonly buffer Yb { vec4 y[]; };
#endif
#define Y y
#endif

layout(push_constant) uniform Push {
  uint outer, C, inner;
  float eps;  // l2normalize
} p;

// The unit (vec4 or one value in .x) starting at value e.
vec4 loadX(uint e) { return VEC4 ? x[e >> 2] : vec4(x[e >> 2][e & 3u]); }
#if OP != OP_ARGMAX
void storeY(uint e, vec4 v) {
  if (VEC4) Y[e >> 2] = v;
  else Y[e >> 2][e & 3u] = v.x;
}
#endif

#if OP == OP_ARGMAX
const uint NONE = 0xffffffffu;  // no index seen yet (lanes with no element)

// v ranks above w: NaN above everything, else greater.
bool above(float v, float w) { return (isnan(v) && !isnan(w)) || v > w; }

shared float argShared[gl_WorkGroupSize.x * gl_WorkGroupSize.y];
shared uint argIndexShared[gl_WorkGroupSize.x * gl_WorkGroupSize.y];

// The lanes' candidates combined in lane order; equal values go to the lower index.
uint lineArgmax(float best, uint index) {
  if (!SPLIT_LINES) return index;
  const uint row = gl_LocalInvocationID.y * gl_WorkGroupSize.x;
  argShared[row + gl_LocalInvocationID.x] = best;
  argIndexShared[row + gl_LocalInvocationID.x] = index;
  barrier();
  float b = 0.0;
  uint bi = NONE;
  for (uint j = 0; j < gl_WorkGroupSize.x; ++j) {
    const float v = argShared[row + j];
    const uint i = argIndexShared[row + j];
    if (i != NONE && (bi == NONE || above(v, b) || (!above(b, v) && i < bi))) {
      b = v;
      bi = i;
    }
  }
  return bi;
}
#endif

void main() {
  const uint line = lineIndex(), lane = lineLane(), lanes = lineLanes(), w = unitWidth();
  const bool live = line < p.outer * p.inner;
  const uint o = live ? line / p.inner : 0u, i = live ? line % p.inner : 0u;
  const uint base = o * p.C * p.inner + i, stride = p.inner;  // stride 1 when VEC4
  const uint units = live ? p.C / w : 0u;  // lines past the end only join the reductions

#if OP == OP_SOFTMAX
  float m = -FLT_MAX, s = 0.0;
  for (uint u = lane; u < units; u += lanes) {
    const vec4 v = loadX(base + u * w * stride);
    const float mNew = max(m, unitMax(v));
    s = s * exp(m - mNew) + unitSum(exp(v - mNew));
    m = mNew;
  }
  const float lineMaximum = lineMax(m);
  const float total = lineSum(s * exp(m - lineMaximum));
  for (uint u = lane; u < units; u += lanes) {
    const uint e = base + u * w * stride;
    storeY(e, total > 0.0 ? exp(loadX(e) - lineMaximum) / total : vec4(0.0));
  }
#elif OP == OP_L2
  float m = 0.0;
  for (uint u = lane; u < units; u += lanes) m = max(m, unitMax(abs(loadX(base + u * w * stride))));
  // The line is scaled by a power of two, 2^-e with max |x| = f * 2^e (f in [0.5, 1)), applied as
  // two factors so that neither is subnormal: a GPU computes x / m as x * (1 / m), and 1 / 3e38
  // is subnormal, which GPUs flush to zero (0 / 0 then). Powers of two scale exactly.
  int e = 0;
  frexp(lineMax(m), e);
  const float down0 = ldexp(1.0, -(e / 2)), down1 = ldexp(1.0, -(e - e / 2));
  float s = 0.0;
  for (uint u = lane; u < units; u += lanes) {
    const vec4 t = (loadX(base + u * w * stride) * down0) * down1;
    s += unitSum(t * t);
  }
  const float scaledNorm = sqrt(lineSum(s));          // ||x|| * 2^-e, in [0.5, sqrt(C)) unless all zero
  const bool aboveEps = ldexp(scaledNorm, e) > p.eps;  // ||x||, which may be +inf: still above eps
  for (uint u = lane; u < units; u += lanes) {
    const uint at = base + u * w * stride;
    const vec4 v = loadX(at);
    storeY(at, aboveEps ? ((v * down0) * down1) / scaledNorm : v / p.eps);
  }
#else
  float best = 0.0;
  uint index = NONE;
  for (uint u = lane; u < units; u += lanes) {
    const vec4 v = loadX(base + u * w * stride);
    for (uint k = 0; k < w; ++k) {
      if (index == NONE || above(v[k], best)) {  // strictly above: the first of equal values stays
        best = v[k];
        index = u * w + k;
      }
    }
  }
  index = lineArgmax(best, index);
  if (live && lane == 0u) Y[line] = int(index);
#endif
}
