#version 450
// The patches of a 2-D convolution as the rows of a matrix (im2col), for convolutions computed
// as GEMMs (engine/ops/conv2d.cpp, conv2dAsIm2colGemm): for the output pixels of a band of
// output rows starting at oy0, p[j][k] = x[ci][oy*S - padY + ky][ox*S - padX + kx] (zero outside
// the image), j = (oy - oy0) * Wo + ox, k = (ci * KH + ky) * KW + kx: the order of the k of
// PyTorch's [Cout, Cin, KH, KW] weight rows. One invocation per element, k fastest: a
// subgroup's lanes write consecutive words.
//! variant im2col_f32
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x_id = 0) in;

TEXEL_INPUT(0, X, 1)
layout(binding = 1) writeonly buffer P { float p[]; };

layout(push_constant) uniform Push {
  int Cin, H, W, Wo, KH, KW, stride, padY, padX;
  int oy0;    // the band's first output row
  int count;  // elements of p: the band's pixels x Cin * KH * KW
  int xBase;  // element 0 of the image in x's binding
} pc;

void main() {
  const int group = int(gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x);  // 2-D grid, x fastest
  const int i = group * int(gl_WorkGroupSize.x) + int(gl_LocalInvocationID.x);
  if (i >= pc.count) return;
  const int taps = pc.KH * pc.KW, K = pc.Cin * taps;
  const int j = i / K, k = i - j * K;
  const int ci = k / taps, t = k - ci * taps, ky = t / pc.KW, kx = t - ky * pc.KW;
  const int row = j / pc.Wo, ox = j - row * pc.Wo;
  const int iy = (pc.oy0 + row) * pc.stride - pc.padY + ky, ix = ox * pc.stride - pc.padX + kx;
  float v = 0.0;
  if (iy >= 0 && iy < pc.H && ix >= 0 && ix < pc.W) v = fetch_X(pc.xBase + (ci * pc.H + iy) * pc.W + ix).x;
  p[i] = v;
}
