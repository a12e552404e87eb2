#version 450
// SAM2.1's image pre-processing as SPAR feeds it (SPAR _sam2_refine_masks, the official
// SAM2Transforms: ToTensor, Resize, Normalize; reference reference/spar_reference/sam2.py
// preprocess). Host side: model/sam2_preprocess.cpp.
//
// image [3, H, W] f32 in [0, 1] (one view of the engine's input images) -> out [3, S, S]:
//   u8 = uint(image * 255)     (SPAR casts to uint8: truncation, in float32)
//   v  = bilinear(u8 / 255) to S x S, PyTorch's align_corners=False: src = (dst + 0.5) * in/out
//        - 0.5 clamped at 0, taps i0 = floor(src) and min(i0 + 1, in - 1)
//   out = (v - mean[c]) / std[c], ImageNet's mean and std (RGB)
// One invocation per output value; the uint8 image is never stored.
//! variant sam2_preprocess
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;

layout(binding = 0) readonly buffer Image { float image[]; };
layout(binding = 1) writeonly buffer Out { float outv[]; };

layout(push_constant) uniform Push {
  uint height, width, out_h, out_w, image_offset;  // image_offset: the view's first float
} p;

const vec3 MEAN = vec3(0.485, 0.456, 0.406);
const vec3 STD = vec3(0.229, 0.224, 0.225);

float u8(uint c, uint y, uint x) {
  // values below 0 (not in a prepared image) clamp to 0 and above 1 to 255, as a uint8 cast
  // of an in-range image gives; an exact k / 255 times 255 is k in float32
  const float v = image[p.image_offset + (c * p.height + y) * p.width + x] * 255.0;
  return float(uint(clamp(v, 0.0, 255.0)));
}

void main() {
  const uint group = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;  // 2-D grid, x fastest
  const uint i = group * gl_WorkGroupSize.x + gl_LocalInvocationID.x;
  const uint plane = p.out_h * p.out_w;
  if (i >= 3u * plane) return;
  const uint c = i / plane, pix = i % plane;
  const uint y = pix / p.out_w, x = pix % p.out_w;

  const float sy = max((float(y) + 0.5) * (float(p.height) / float(p.out_h)) - 0.5, 0.0);
  const float sx = max((float(x) + 0.5) * (float(p.width) / float(p.out_w)) - 0.5, 0.0);
  const uint y0 = uint(sy), x0 = uint(sx);
  const uint y1 = min(y0 + 1u, p.height - 1u), x1 = min(x0 + 1u, p.width - 1u);
  const float ly = sy - float(y0), lx = sx - float(x0);
  const float top = (1.0 - lx) * u8(c, y0, x0) + lx * u8(c, y0, x1);
  const float bottom = (1.0 - lx) * u8(c, y1, x0) + lx * u8(c, y1, x1);
  const float v = ((1.0 - ly) * top + ly * bottom) / 255.0;
  outv[i] = (v - MEAN[c]) / STD[c];
}
