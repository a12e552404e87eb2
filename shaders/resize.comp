#version 450
// Bilinear resize of NCHW images to an explicit output size, PyTorch's
// F.interpolate(mode='bilinear', antialias=False) semantics:
//   align_corners = false: src = (dst + 0.5) * in / out - 0.5, clamped below at 0;
//   align_corners = true:  src = dst * (in - 1) / (out - 1), or 0 when out == 1;
// neighbours floor(src) and min(floor(src) + 1, in - 1), weight frac(src).
// Host side: engine/ops/resize.cpp.
//
// Source coordinates are exact rationals num / den in integers (no rounding of the scale
// factor), and each output is x0 + l * (x1 - x0), so constant images stay exactly constant.
// An invocation computes RX consecutive output columns of one row for RC channels,
// sharing the coordinate arithmetic.
//
// ARGMAX: the channels are scores and the output is, per output pixel, the index of the first
// channel whose interpolated score is the largest (torch's argmax over dim 1 of the resized
// scores), written as int [N, Ho, Wo]: the resized scores are never stored. An invocation then
// takes all C channels of its RX columns (a work unit is one image).
//! variant resize_bilinear_f32 ARGMAX=0
//! variant resize_bilinear_argmax_i32 ARGMAX=1
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const int RX = 4;  // consecutive output columns per invocation
layout(constant_id = 4) const int RC = 4;  // channels per invocation
layout(constant_id = 5) const bool ALIGN_CORNERS = false;

TEXEL_INPUT(0, X, 1)
#if ARGMAX
layout(binding = 1) writeonly buffer Y { int y[]; };
#else
layout(binding = 1) writeonly buffer Y { float y[]; };
#endif

layout(push_constant) uniform Push {
  int C, H, W, Ho, Wo;
  int cBlocks;   // ceil(C / RC); 1 with ARGMAX
  int zBase;     // first (image, channel block) unit of this dispatch
  int inBase;    // element of x at texel 0 of X
  int outBase;   // element of the output tensor at y[0]
} p;

// Source index and weight of output position dst along an axis of in -> out samples.
void sourceCoord(int dst, int inSize, int outSize, out int i0, out int i1, out float lambda) {
  int num, den;
  if (ALIGN_CORNERS) {
    num = dst * (inSize - 1);
    den = max(outSize - 1, 1);  // out == 1: num = 0, src = 0
  } else {
    num = max((2 * dst + 1) * inSize - outSize, 0);
    den = 2 * outSize;
  }
  i0 = num / den;
  lambda = float(num - i0 * den) / float(den);
  i1 = min(i0 + 1, inSize - 1);
}

void main() {
  const int ox0 = int(gl_GlobalInvocationID.x) * RX;
  const int oy = int(gl_GlobalInvocationID.y);
  if (ox0 >= p.Wo || oy >= p.Ho) return;
  const int unit = p.zBase + int(gl_GlobalInvocationID.z);
  const int n = unit / p.cBlocks;
  const int c0 = (unit - n * p.cBlocks) * RC;

  int y0, y1;
  float ly;
  sourceCoord(oy, p.H, p.Ho, y0, y1, ly);
  int x0[RX], x1[RX];
  float lx[RX];
  [[unroll]] for (int i = 0; i < RX; ++i) sourceCoord(min(ox0 + i, p.Wo - 1), p.W, p.Wo, x0[i], x1[i], lx[i]);

#if ARGMAX
  float best[RX];
  int arg[RX];
  for (int ch = 0; ch < p.C; ++ch) {
    const int plane = (n * p.C + ch) * p.H * p.W - p.inBase;
    const int r0 = plane + y0 * p.W, r1 = plane + y1 * p.W;
    [[unroll]] for (int i = 0; i < RX; ++i) {
      const float a = fetch_X(r0 + x0[i]).x, b = fetch_X(r0 + x1[i]).x;
      const float d = fetch_X(r1 + x0[i]).x, e = fetch_X(r1 + x1[i]).x;
      const float top = fma(lx[i], b - a, a), bottom = fma(lx[i], e - d, d);
      const float v = fma(ly, bottom - top, top);
      if (ch == 0 || v > best[i]) {  // strictly larger: the first maximum wins
        best[i] = v;
        arg[i] = ch;
      }
    }
  }
  const int outRow = (n * p.Ho + oy) * p.Wo - p.outBase;
  [[unroll]] for (int i = 0; i < RX; ++i)
    if (ox0 + i < p.Wo) y[outRow + ox0 + i] = arg[i];
#else
  [[unroll]] for (int c = 0; c < RC; ++c) {
    const int ch = c0 + c;
    if (ch >= p.C) break;
    const int plane = (n * p.C + ch) * p.H * p.W - p.inBase;
    const int r0 = plane + y0 * p.W, r1 = plane + y1 * p.W;
    const int outRow = ((n * p.C + ch) * p.Ho + oy) * p.Wo - p.outBase;
    [[unroll]] for (int i = 0; i < RX; ++i) {
      if (ox0 + i >= p.Wo) break;
      const float a = fetch_X(r0 + x0[i]).x, b = fetch_X(r0 + x1[i]).x;
      const float d = fetch_X(r1 + x0[i]).x, e = fetch_X(r1 + x1[i]).x;
      const float top = fma(lx[i], b - a, a), bottom = fma(lx[i], e - d, d);
      y[outRow + ox0 + i] = fma(ly, bottom - top, top);
    }
  }
#endif
}
