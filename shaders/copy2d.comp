#version 450
// Strided 2-D copy: dst[r * dstStride + dstCol + c] = src[r * srcStride + srcCol + c] for
// r < rows, c < cols: concatenation and slicing along columns or channels.
// Host side: engine/ops/copy2d.cpp.
// VEC4 (cols, strides and columns all multiples of 4): every invocation copies one vec4;
// otherwise one value, addressed as a component of the vec4 arrays.
//! variant copy2d
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const bool VEC4 = false;

layout(binding = 0) readonly buffer Src { vec4 src[]; };
layout(binding = 1) writeonly buffer Dst { vec4 dst[]; };

layout(push_constant) uniform Push {
  uint rows, cols;  // in values
  uint srcStride, srcCol;
  uint dstStride, dstCol;
} p;

void main() {
  const uint group = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;  // 2-D grid, x fastest
  const uint i = group * gl_WorkGroupSize.x + gl_LocalInvocationID.x;
  const uint width = VEC4 ? p.cols / 4u : p.cols;  // units per row
  if (i >= p.rows * width) return;
  const uint r = i / width, c = i % width;
  if (VEC4) {
    dst[(r * p.dstStride + p.dstCol) / 4u + c] = src[(r * p.srcStride + p.srcCol) / 4u + c];
  } else {
    const uint s = r * p.srcStride + p.srcCol + c, d = r * p.dstStride + p.dstCol + c;
    dst[d >> 2][d & 3u] = src[s >> 2][s & 3u];
  }
}
