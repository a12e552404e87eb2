#version 450
// Hiera's window layout and q pooling (official hieradet window_partition, window_unpartition,
// do_pool with MaxPool2d(2, 2)) and the FPN neck's top-down step (image_encoder.FpnNeck:
// nearest x2 added to the lateral); reference reference/spar_reference/sam2.py. Host side:
// model/sam2_windows.cpp. Tokens are channel-last: a map is [H, W, C], windows [nW, w, w, C]
// with the nW = nWy x nWx windows row-major and the tokens of a window row-major.
//   sam2_window_partition  x [H, W, C] -> y [nW, w, w, C]; the grid padded at the bottom and
//                          right to multiples of w with zeros (which the qkv projection then
//                          turns into its bias: the pad tokens stay keys and values)
//   sam2_window_merge      y [nW, w, w, C] -> x [H, W, C], nWx = ceil(W / w): the windows laid
//                          back and the padding cropped
//   sam2_max_pool2x2       x [B, H, W, C] -> y [B, H / 2, W / 2, C] (floor), the max of 2 x 2
//   sam2_add_nearest_up2x  y [H, W, C] = lateral [H, W, C] + coarse [H / 2, W / 2, C] at
//                          (y / 2, x / 2): F.interpolate(scale_factor=2, mode="nearest")
//   sam2_channels_last     x [C, H, W] -> y [H * W, C] (the patch embedding's output as tokens)
// One invocation per output value.
//! variant sam2_window_partition MODE=0
//! variant sam2_window_merge MODE=1
//! variant sam2_max_pool2x2 MODE=2
//! variant sam2_add_nearest_up2x MODE=3
//! variant sam2_channels_last MODE=4
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;

layout(binding = 0) readonly buffer In { float xin[]; };
layout(binding = 1) writeonly buffer Out { float yout[]; };
#if MODE == 3
layout(binding = 2) readonly buffer Coarse { float coarse[]; };
#endif

layout(push_constant) uniform Push {
  uint total;     // output values
  uint h, w, c;   // the map's height, width (partition: input; merge: output; pool: input), channels
  uint win;       // window side (partition, merge)
  uint nwx;       // windows per row (partition, merge)
} p;

void main() {
  const uint group = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;  // 2-D grid, x fastest
  const uint i = group * gl_WorkGroupSize.x + gl_LocalInvocationID.x;
  if (i >= p.total) return;
  const uint c = i % p.c, t = i / p.c;
#if MODE == 0
  const uint ww = p.win * p.win, window = t / ww, pos = t % ww;
  const uint y = (window / p.nwx) * p.win + pos / p.win, x = (window % p.nwx) * p.win + pos % p.win;
  yout[i] = (y < p.h && x < p.w) ? xin[(y * p.w + x) * p.c + c] : 0.0;
#elif MODE == 1
  const uint y = t / p.w, x = t % p.w;
  const uint window = (y / p.win) * p.nwx + x / p.win, pos = (y % p.win) * p.win + x % p.win;
  yout[i] = xin[(window * p.win * p.win + pos) * p.c + c];
#elif MODE == 3
  const uint y = t / p.w, x = t % p.w;
  yout[i] = xin[i] + coarse[((y / 2u) * (p.w / 2u) + x / 2u) * p.c + c];
#elif MODE == 4
  yout[i] = xin[c * p.h * p.w + t];
#else
  const uint ho = p.h / 2u, wo = p.w / 2u;
  const uint b = t / (ho * wo), r = t % (ho * wo), y = 2u * (r / wo), x = 2u * (r % wo);
  const uint base = b * p.h * p.w;
  yout[i] = max(max(xin[(base + y * p.w + x) * p.c + c], xin[(base + y * p.w + x + 1u) * p.c + c]),
                max(xin[(base + (y + 1u) * p.w + x) * p.c + c], xin[(base + (y + 1u) * p.w + x + 1u) * p.c + c]));
#endif
}
