#version 450
// Cameras from the pose estimator's heads (reference/spar_reference/spar.py
// PoseEstimator.forward + cam_info_to_se3 + rot6d_to_mat; official model/rayzer.PoseEstimator,
// get_cam_se3, utils/pose_utils.rot6d2mat). Host side: model/pose_head.cpp.
//
// rel [B, V-1, 9]: rel_head outputs of the non-canonical views in view order (raw: the
// identity offset [1,0,0, 0,1,0 | 0,0,0] is added here, as the reference adds it after the
// head); kraw [B]: canonical_k_head output (raw: + 1.25 here). Per view (b, v):
//   rt = identity offset (+ rel of that view unless v is the canonical view)
//   R = [b1 b2 b1xb2] (columns), b1 = normalize(a1), b2 = a2 - (b1.a2) b1 twice, normalized
//   c2w = [R | t; 0 0 0 1], fxfycxcy = (f, f, 0.5, 0.5), f = kraw + 1.25
// normalize(x) is F.normalize: x / max(|x|, 1e-12), with |x| taken of x scaled by its largest
// component (no underflow of the squares when a1 and a2 are nearly collinear and the residual
// b2 is tiny). One invocation per view.
//! variant pose_head
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;

layout(binding = 0) readonly buffer Rel { float rel[]; };
layout(binding = 1) readonly buffer Kraw { float kraw[]; };
layout(binding = 2) writeonly buffer C2w { float c2w[]; };
layout(binding = 3) writeonly buffer Kout { float kout[]; };

layout(push_constant) uniform Push {
  uint batch, views, canonical;
} p;

const float F_BIAS = 1.25;
const float NORM_EPS = 1e-12;  // F.normalize's default

float robustLength(vec3 a) {
  const float s = max(max(abs(a.x), abs(a.y)), abs(a.z));
  if (s == 0.0 || isinf(s)) return s;
  const vec3 u = a / s;
  return s * sqrt(dot(u, u));
}

vec3 normalizeEps(vec3 a) { return a / max(robustLength(a), NORM_EPS); }

void main() {
  const uint i = gl_GlobalInvocationID.x;
  if (i >= p.batch * p.views) return;
  const uint b = i / p.views, v = i % p.views;

  float rt[9] = float[9](1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0);
  if (v != p.canonical) {
    const uint r = b * (p.views - 1u) + (v < p.canonical ? v : v - 1u);
    [[unroll]] for (int j = 0; j < 9; ++j) rt[j] += rel[r * 9u + uint(j)];
  }
  const vec3 a1 = vec3(rt[0], rt[1], rt[2]), a2 = vec3(rt[3], rt[4], rt[5]);
  const vec3 b1 = normalizeEps(a1);
  vec3 b2 = a2 - dot(b1, a2) * b1;
  b2 = b2 - dot(b1, b2) * b1;  // "twice is enough" (the reference's reorthogonalize)
  b2 = normalizeEps(b2);
  const vec3 b3 = cross(b1, b2);

  const uint m = i * 16u;
  c2w[m + 0u] = b1.x;  c2w[m + 1u] = b2.x;  c2w[m + 2u] = b3.x;  c2w[m + 3u] = rt[6];
  c2w[m + 4u] = b1.y;  c2w[m + 5u] = b2.y;  c2w[m + 6u] = b3.y;  c2w[m + 7u] = rt[7];
  c2w[m + 8u] = b1.z;  c2w[m + 9u] = b2.z;  c2w[m + 10u] = b3.z; c2w[m + 11u] = rt[8];
  c2w[m + 12u] = 0.0;  c2w[m + 13u] = 0.0;  c2w[m + 14u] = 0.0;  c2w[m + 15u] = 1.0;

  const float f = kraw[b] + F_BIAS;
  kout[i * 4u + 0u] = f;
  kout[i * 4u + 1u] = f;
  kout[i * 4u + 2u] = 0.5;
  kout[i * 4u + 3u] = 0.5;
}
