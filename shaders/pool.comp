#version 450
// Average pooling with kernel k, stride k, no padding (PyTorch nn.AvgPool2d(k)):
// y[n][c][oy][ox] = (sum_{i,j < k} x[n][c][oy*k + i][ox*k + j]) / (k*k), Ho = floor(H / k).
// Host side: engine/ops/pool.cpp.
//
// An invocation computes RX consecutive output columns of one row for RC channels; rows
// and columns of the remainder (H % k, W % k) are never read.
//! variant avg_pool2d_f32
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const int RX = 4;  // consecutive output columns per invocation
layout(constant_id = 4) const int RC = 4;  // channels per invocation

TEXEL_INPUT(0, X, 1)
layout(binding = 1) writeonly buffer Y { float y[]; };

layout(push_constant) uniform Push {
  int C, H, W, Ho, Wo, K;
  int cBlocks;   // ceil(C / RC)
  int zBase;     // first (image, channel block) unit of this dispatch
  int inBase;    // element of x at texel 0 of X
  int outBase;   // element of the output tensor at y[0]
} p;

void main() {
  const int ox0 = int(gl_GlobalInvocationID.x) * RX;
  const int oy = int(gl_GlobalInvocationID.y);
  if (ox0 >= p.Wo || oy >= p.Ho) return;
  const int unit = p.zBase + int(gl_GlobalInvocationID.z);
  const int n = unit / p.cBlocks;
  const int c0 = (unit - n * p.cBlocks) * RC;
  const float count = float(p.K * p.K);

  [[unroll]] for (int c = 0; c < RC; ++c) {
    const int ch = c0 + c;
    if (ch >= p.C) break;
    float sum[RX];
    [[unroll]] for (int i = 0; i < RX; ++i) sum[i] = 0.0;
    // Columns past the output's edge re-read the last window; their sums are dropped.
    int col[RX];
    [[unroll]] for (int i = 0; i < RX; ++i) col[i] = min(ox0 + i, p.Wo - 1) * p.K;
    int row = ((n * p.C + ch) * p.H + oy * p.K) * p.W - p.inBase;
    for (int ky = 0; ky < p.K; ++ky, row += p.W)
      for (int kx = 0; kx < p.K; ++kx)
        [[unroll]] for (int i = 0; i < RX; ++i) sum[i] += fetch_X(row + col[i] + kx).x;
    const int outRow = ((n * p.C + ch) * p.Ho + oy) * p.Wo - p.outBase;
    [[unroll]] for (int i = 0; i < RX; ++i) {
      if (ox0 + i >= p.Wo) break;
      y[outRow + ox0 + i] = sum[i] / count;
    }
  }
}
