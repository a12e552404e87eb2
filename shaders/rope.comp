#version 450
// Rotary position embedding of q and k inside a fused qkv tensor, in place. Host side:
// engine/ops/rope.cpp. Each token row holds q heads at columns [0, D) and k heads at [D, 2D)
// (D = heads * dh), so the 2 * heads rotated heads are consecutive blocks of dh values. For a
// head x = [a, b] (halves of dh / 2) of rotated token t (token prefix + t of its image):
//   x' = x * cos[t] + rotate_half(x) * sin[t],  rotate_half([a, b]) = [-b, a]
// i.e. a' = a * cos[t][j] - b * sin[t][j],  b' = b * cos[t][j + dh/2] + a * sin[t][j + dh/2].
// The sin / cos tables ([tokens, dh], built on the host in double) are read as given: no
// assumption that their halves repeat.
// Every invocation handles one unit of a half head: a vec4 of 4 consecutive pairs when VEC4
// (llvmpipe loads a vec4 for about the cost of a float), else one pair.
//! variant rope_f32
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const bool VEC4 = false;

// f32 values, declared as vec4s for VEC4 loads.
layout(binding = 0) buffer QKV { vec4 x[]; };
layout(binding = 1) readonly buffer SinT { vec4 sinT[]; };
layout(binding = 2) readonly buffer CosT { vec4 cosT[]; };

layout(push_constant) uniform Push {
  uint items;     // rotated rows * 2 * heads * unitsPerHalf in this dispatch
  uint rotated;   // rotated tokens per image (table rows)
  uint prefix;    // leading tokens of each image left untouched
  uint tokens;    // tokens per image (prefix + rotated)
  uint stride;    // values per token row
  uint heads2;    // 2 * heads: q heads then k heads
  uint dh;        // head dim
  uint units;     // units per half head: dh / 2 / (VEC4 ? 4 : 1)
} p;

vec4 loadUnit(uint e) { return VEC4 ? x[e >> 2] : vec4(x[e >> 2][e & 3u]); }
vec4 loadSin(uint e) { return VEC4 ? sinT[e >> 2] : vec4(sinT[e >> 2][e & 3u]); }
vec4 loadCos(uint e) { return VEC4 ? cosT[e >> 2] : vec4(cosT[e >> 2][e & 3u]); }
void storeUnit(uint e, vec4 v) {
  if (VEC4) x[e >> 2] = v;
  else x[e >> 2][e & 3u] = v.x;
}

void main() {
  const uint group = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;  // 2-D grid, x fastest
  const uint item = group * gl_WorkGroupSize.x + gl_LocalInvocationID.x;
  if (item >= p.items) return;
  const uint unit = item % p.units;
  const uint headRow = item / p.units;
  const uint head = headRow % p.heads2;
  const uint row = headRow / p.heads2;  // rotated row over all images of the dispatch
  const uint image = row / p.rotated, t = row % p.rotated;

  const uint halfDh = p.dh / 2u;
  const uint j = unit * (VEC4 ? 4u : 1u);
  const uint ea = (image * p.tokens + p.prefix + t) * p.stride + head * p.dh + j, eb = ea + halfDh;
  const uint ta = t * p.dh + j, tb = ta + halfDh;
  const vec4 a = loadUnit(ea), b = loadUnit(eb);
  storeUnit(ea, a * loadCos(ta) - b * loadSin(ta));
  storeUnit(eb, b * loadCos(tb) + a * loadSin(tb));
}
