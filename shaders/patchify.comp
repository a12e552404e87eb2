#version 450
// Patchify and its inverse between NCHW images and patch tokens:
//   images [V, C, H, W] <-> tokens [V, (H/P)*(W/P), P*P*C], token features in (ph pw c)
//   order (channel fastest): einops "b c (hh ph) (ww pw) -> b (hh ww) (ph pw c)".
// Host side: engine/ops/patchify.cpp. A pure copy: results are bit-exact.
//
// DIRECTION 0 (patchify) writes tokens: x runs along features, y along tokens, z over images.
// DIRECTION 1 (unpatchify) writes images: x runs along columns, y along rows, z over
// (image, channel) planes. An invocation writes RX consecutive outputs.
//! variant patchify_f32 DIRECTION=0
//! variant unpatchify_f32 DIRECTION=1
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const int RX = 4;  // consecutive outputs per invocation

TEXEL_INPUT(0, X, 1)
layout(binding = 1) writeonly buffer Y { float y[]; };

layout(push_constant) uniform Push {
  int C, H, W, P;
  int zBase;     // first unit (image, or image plane for unpatchify) of this dispatch
  int inBase;    // element of the input tensor at texel 0 of X
  int outBase;   // element of the output tensor at y[0]
} p;

void main() {
  const int i0 = int(gl_GlobalInvocationID.x) * RX;
  const int row = int(gl_GlobalInvocationID.y);
  const int unit = p.zBase + int(gl_GlobalInvocationID.z);
  const int Wp = p.W / p.P;                   // patches per image row
  const int T = (p.H / p.P) * Wp, F = p.P * p.P * p.C;
#if DIRECTION == 0
  // row = token t, i = feature f = (ph * P + pw) * C + c
  if (i0 >= F || row >= T) return;
  const int v = unit;
  const int hh = row / Wp, ww = row - hh * Wp;
  const int outStart = (v * T + row) * F - p.outBase;
  // Decompose the first feature once, then step (c, pw, ph) like an odometer: integer
  // division does not vectorize on a CPU device.
  const int pix0 = i0 / p.C;
  int c = i0 - pix0 * p.C, ph = pix0 / p.P, pw = pix0 - ph * p.P;
  const int imageStart = v * p.C * p.H * p.W + (hh * p.W + ww) * p.P - p.inBase;
  [[unroll]] for (int j = 0; j < RX; ++j) {
    const int f = i0 + j;
    if (f >= F) break;
    y[outStart + f] = fetch_X(imageStart + (c * p.H + ph) * p.W + pw).x;
    if (++c == p.C) {
      c = 0;
      if (++pw == p.P) { pw = 0; ++ph; }
    }
  }
#else
  // row = image row, i = image column; unit = (image v, channel c) plane
  if (i0 >= p.W || row >= p.H) return;
  const int v = unit / p.C, c = unit - v * p.C;
  const int hh = row / p.P, ph = row - hh * p.P;
  const int outStart = (unit * p.H + row) * p.W - p.outBase;
  // Step (ww, pw) from the first column on (no division per element).
  int ww = i0 / p.P, pw = i0 - ww * p.P;
  const int rowStart = (v * T + hh * Wp) * F + ph * p.P * p.C + c - p.inBase;
  [[unroll]] for (int j = 0; j < RX; ++j) {
    const int x = i0 + j;
    if (x >= p.W) break;
    y[outStart + x] = fetch_X(rowStart + ww * F + pw * p.C).x;
    if (++pw == p.P) { pw = 0; ++ww; }
  }
#endif
}
