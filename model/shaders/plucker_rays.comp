#version 450
// Plücker rays of pinhole cameras (reference/spar_reference/spar.py plucker_rays, the official
// model/rayzer.cam_info_to_plucker). Host side: model/plucker_rays.cpp.
//
// c2w [V, 4, 4] (OpenCV: +z forward, row-major, [R | t]), fxfycxcy [V, 4] normalized by the
// image size -> rays [V, 6, H, W], channels [o x d, d] with o = t and, at pixel centre
// (x + 0.5, y + 0.5), d = normalize(R [(x+0.5-cx)/fx, (y+0.5-cy)/fy, 1]) where fx, cx are
// multiplied by W and fy, cy by H. One invocation per pixel of one view.
//
// The norm is taken of d scaled by its largest component, so neither the squares overflow
// (focal -> 0) nor underflow (focal -> inf); the z component of the camera-frame vector is
// 1 and R is a rotation, so the largest component is never 0 for a proper rotation; a zero
// vector (degenerate R) gives d = 0 rather than NaN.
//! variant plucker_rays
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;

layout(binding = 0) readonly buffer C2w { float c2w[]; };
layout(binding = 1) readonly buffer K { float k[]; };
layout(binding = 2) writeonly buffer Rays { float rays[]; };

layout(push_constant) uniform Push {
  uint views, height, width;
} p;

void main() {
  const uint group = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;  // 2-D grid, x fastest
  const uint i = group * gl_WorkGroupSize.x + gl_LocalInvocationID.x;
  const uint hw = p.height * p.width;
  if (i >= p.views * hw) return;
  const uint v = i / hw, pix = i % hw;
  const uint y = pix / p.width, x = pix % p.width;

  const float fx = k[v * 4u + 0u] * float(p.width);
  const float fy = k[v * 4u + 1u] * float(p.height);
  const float cx = k[v * 4u + 2u] * float(p.width);
  const float cy = k[v * 4u + 3u] * float(p.height);
  const vec3 cam = vec3((float(x) + 0.5 - cx) / fx, (float(y) + 0.5 - cy) / fy, 1.0);

  const uint m = v * 16u;
  vec3 d = vec3(dot(vec3(c2w[m + 0u], c2w[m + 1u], c2w[m + 2u]), cam),
                dot(vec3(c2w[m + 4u], c2w[m + 5u], c2w[m + 6u]), cam),
                dot(vec3(c2w[m + 8u], c2w[m + 9u], c2w[m + 10u]), cam));
  const float s = max(max(abs(d.x), abs(d.y)), abs(d.z));
  if (s > 0.0 && !isinf(s)) {
    d /= s;
    d /= sqrt(dot(d, d));  // in [1, sqrt(3)]
  } else {
    d = s > 0.0 ? normalize(vec3(isinf(d.x) ? sign(d.x) : 0.0, isinf(d.y) ? sign(d.y) : 0.0,
                                 isinf(d.z) ? sign(d.z) : 0.0))
                : vec3(0.0);
  }
  const vec3 o = vec3(c2w[m + 3u], c2w[m + 7u], c2w[m + 11u]);
  const vec3 oxd = cross(o, d);

  const uint base = v * 6u * hw + pix;
  rays[base + 0u * hw] = oxd.x;
  rays[base + 1u * hw] = oxd.y;
  rays[base + 2u * hw] = oxd.z;
  rays[base + 3u * hw] = d.x;
  rays[base + 4u * hw] = d.y;
  rays[base + 5u * hw] = d.z;
}
