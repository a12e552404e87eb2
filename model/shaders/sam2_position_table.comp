#version 450
// SAM2.1's Hiera position table (official hieradet.Hiera._get_pos_embed; reference
// reference/spar_reference/sam2.py position_embedding). Host side: model/sam2_position_table.cpp.
//
// background [C, Hb, Wb] (pos_embed, 7x7 or 14x14) resized bicubically to side x side as
// PyTorch's interpolate(mode="bicubic", align_corners=False) does it, plus window [C, w, w]
// (pos_embed_window) tiled: out[y * side + x, c] (token-major, channel last, the layout of
// Hiera's tokens). One invocation per output value.
//
// PyTorch's bicubic: src = (dst + 0.5) * (in / out) - 0.5, NOT clamped; t = src - floor(src);
// the four taps floor-1 .. floor+2 clamped to [0, in - 1]; cubic-convolution weights with
// A = -0.75. Input-independent: computed once per model load.
//! variant sam2_position_table
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;

layout(binding = 0) readonly buffer Background { float background[]; };
layout(binding = 1) readonly buffer Window { float window[]; };
layout(binding = 2) writeonly buffer Table { float table[]; };

layout(push_constant) uniform Push {
  uint channels, bg_h, bg_w, side, win;
} p;

const float A = -0.75;

// The 4 weights of taps floor-1 .. floor+2 for fractional offset t.
vec4 cubicWeights(float t) {
  const float x0 = t + 1.0, x1 = t, x2 = 1.0 - t, x3 = 2.0 - t;
  return vec4(((A * x0 - 5.0 * A) * x0 + 8.0 * A) * x0 - 4.0 * A,
              ((A + 2.0) * x1 - (A + 3.0)) * x1 * x1 + 1.0,
              ((A + 2.0) * x2 - (A + 3.0)) * x2 * x2 + 1.0,
              ((A * x3 - 5.0 * A) * x3 + 8.0 * A) * x3 - 4.0 * A);
}

void main() {
  const uint group = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;  // 2-D grid, x fastest
  const uint i = group * gl_WorkGroupSize.x + gl_LocalInvocationID.x;
  if (i >= p.side * p.side * p.channels) return;
  const uint c = i % p.channels, token = i / p.channels;
  const uint y = token / p.side, x = token % p.side;

  const float sy = (float(y) + 0.5) * (float(p.bg_h) / float(p.side)) - 0.5;
  const float sx = (float(x) + 0.5) * (float(p.bg_w) / float(p.side)) - 0.5;
  const float fy = floor(sy), fx = floor(sx);
  const vec4 wy = cubicWeights(sy - fy), wx = cubicWeights(sx - fx);
  const int iy = int(fy), ix = int(fx);
  const uint plane = c * p.bg_h * p.bg_w;
  float acc = 0.0;
  [[unroll]] for (int a = 0; a < 4; ++a) {
    const uint row = uint(clamp(iy - 1 + a, 0, int(p.bg_h) - 1));
    float r = 0.0;
    [[unroll]] for (int b = 0; b < 4; ++b) {
      const uint col = uint(clamp(ix - 1 + b, 0, int(p.bg_w) - 1));
      r += wx[b] * background[plane + row * p.bg_w + col];
    }
    acc += wy[a] * r;
  }
  table[i] = acc + window[(c * p.win + y % p.win) * p.win + x % p.win];
}
