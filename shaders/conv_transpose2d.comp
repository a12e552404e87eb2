#version 450
// Transposed 2-D convolution with kernel == stride and no padding (PyTorch
// nn.ConvTranspose2d(Cin, Cout, kernel_size=S, stride=S)): every input pixel expands into
// an S x S output patch,
//   y[n][co][oy][ox] = act(b[co] + sum_ci x[n][ci][oy/S][ox/S] * w[ci][co][oy%S][ox%S]).
// Host side: engine/ops/conv_transpose2d.cpp.
//
// Laid out for llvmpipe like conv2d.comp: texel-buffer reads, no shared memory, and a
// register block per invocation of RC output channels x RY input rows x RX consecutive
// input columns (RC x RY*S x RX*S outputs). Consecutive invocations along x take
// consecutive column blocks. The S*S weights of one (ci, co) pair are contiguous in
// PyTorch's [Cin, Cout, S, S] layout: RGBA texels when S*S is a multiple of 4.
//! variant conv_transpose2d_f32 OUT4=0
//! variant conv_transpose2d_f32_out4 OUT4=1
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const int S = 2;          // kernel size == stride
layout(constant_id = 4) const int RC = 16;        // output channels per invocation
layout(constant_id = 5) const int RY = 1;         // input rows per invocation
layout(constant_id = 6) const int RX = 8;         // consecutive input columns per invocation
layout(constant_id = 7) const int TEXEL_W = 4;    // weights per texel: 4 (RGBA) or 1 (R)
layout(constant_id = 8) const int TEXEL_X = 4;    // input columns per texel: 4 (W, RX multiples of 4) or 1
layout(constant_id = 9) const int ACT = ACT_NONE;
layout(constant_id = 10) const bool HAS_BIAS = false;
// FLAT: invocations along x walk the RY x RX input blocks row-major across block rows (as in
// conv2d.comp), so small inputs (16x16: 4 column blocks) still fill a CPU's SIMD lanes.
layout(constant_id = 11) const bool FLAT = false;

TEXEL_INPUT(0, X, TEXEL_X)
TEXEL_INPUT(1, W, TEXEL_W)
TEXEL_INPUT(2, BIAS, 1)  // R texels; bound to w when HAS_BIAS is false
// OUT4: y is written as whole vec4s (the host guarantees RX*S, Wo and outBase multiples of 4):
// as in conv2d.comp, llvmpipe scatters each store lane by lane, and with few input channels
// the stores dominate.
#if OUT4
layout(binding = 3) writeonly buffer Y { vec4 y[]; };
#else
layout(binding = 3) writeonly buffer Y { float y[]; };
#endif

layout(push_constant) uniform Push {
  int Cin, H, W, Cout;
  int coBlocks;                  // ceil(Cout / RC)
  int zBase;                     // first (image, channel block) unit of this dispatch
  int inBase, wBase, biasBase;   // element of x, w, bias at texel 0 of X, W, BIAS
  int outBase;                   // element of the output tensor at y[0]
} p;

const int SS = S * S;
const int OUT_BLOCK = RY * RX * SS;  // outputs per channel

void main() {
  int bx = int(gl_GlobalInvocationID.x), by = int(gl_GlobalInvocationID.y);
  if (FLAT) {
    const int colBlocks = (p.W + RX - 1) / RX;
    by = bx / colBlocks;
    bx -= by * colBlocks;
  }
  const int ix0 = bx * RX;
  const int iy0 = by * RY;
  if (ix0 >= p.W || iy0 >= p.H) return;
  const int unit = p.zBase + int(gl_GlobalInvocationID.z);
  const int n = unit / p.coBlocks;
  const int co0 = (unit - n * p.coBlocks) * RC;

  // Columns and rows past the edge re-read the last one; their outputs are dropped.
  int xOff[RY * RX];
  [[unroll]] for (int r = 0; r < RY; ++r)
    [[unroll]] for (int c = 0; c < RX; ++c)
      xOff[r * RX + c] = min(iy0 + r, p.H - 1) * p.W + min(ix0 + c, p.W - 1);
  int wOff[RC];
  [[unroll]] for (int c = 0; c < RC; ++c) wOff[c] = min(co0 + c, p.Cout - 1) * SS - p.wBase;

  float acc[RC * OUT_BLOCK];
  [[unroll]] for (int i = 0; i < RC * OUT_BLOCK; ++i) acc[i] = 0.0;

  const int plane = p.H * p.W;
  int xBase = n * p.Cin * plane - p.inBase;
  int wBase = 0;
  for (int ci = 0; ci < p.Cin; ++ci, xBase += plane, wBase += p.Cout * SS) {
    float v[RY * RX];
    if (TEXEL_X == 4) {
      [[unroll]] for (int r = 0; r < RY; ++r)
        [[unroll]] for (int t = 0; t < RX / 4; ++t) {
          const vec4 q = fetch_X((xBase + xOff[r * RX + 4 * t]) / 4);
          [[unroll]] for (int j = 0; j < 4; ++j) v[r * RX + 4 * t + j] = q[j];
        }
    } else {
      [[unroll]] for (int i = 0; i < RY * RX; ++i) v[i] = fetch_X(xBase + xOff[i]).x;
    }
    [[unroll]] for (int c = 0; c < RC; ++c) {
      float wv[SS];
      if (TEXEL_W == 4) {
        [[unroll]] for (int t = 0; t < SS / 4; ++t) {
          const vec4 q = fetch_W((wBase + wOff[c]) / 4 + t);
          [[unroll]] for (int j = 0; j < 4; ++j) wv[4 * t + j] = q[j];
        }
      } else {
        [[unroll]] for (int t = 0; t < SS; ++t) wv[t] = fetch_W(wBase + wOff[c] + t).x;
      }
      // acc index: channel, input row, kernel row, input column, kernel column, so that
      // each output row of the block is contiguous.
      [[unroll]] for (int r = 0; r < RY; ++r)
        [[unroll]] for (int ky = 0; ky < S; ++ky)
          [[unroll]] for (int px = 0; px < RX; ++px)
            [[unroll]] for (int kx = 0; kx < S; ++kx) {
              const int i = c * OUT_BLOCK + ((r * S + ky) * RX + px) * S + kx;
              acc[i] = fma(v[r * RX + px], wv[ky * S + kx], acc[i]);
            }
    }
  }

  const int Ho = p.H * S, Wo = p.W * S;
  const int oxEnd = min(RX * S, Wo - ix0 * S);  // valid outputs along x in the block
  [[unroll]] for (int c = 0; c < RC; ++c) {
    const int co = co0 + c;
    if (co >= p.Cout) break;
    const float b = HAS_BIAS ? fetch_BIAS(co - p.biasBase).x : 0.0;
    [[unroll]] for (int row = 0; row < RY * S; ++row) {
      const int oy = iy0 * S + row;
      if (oy >= Ho) break;
      const int rowStart = ((n * p.Cout + co) * Ho + oy) * Wo + ix0 * S - p.outBase;
#if OUT4
      [[unroll]] for (int q = 0; q < RX * S / 4; ++q) {
        if (4 * q >= oxEnd) break;
        const int i = c * OUT_BLOCK + row * RX * S + 4 * q;
        y[rowStart / 4 + q] = vec4(activate(acc[i] + b, ACT), activate(acc[i + 1] + b, ACT),
                                   activate(acc[i + 2] + b, ACT), activate(acc[i + 3] + b, ACT));
      }
#else
      [[unroll]] for (int col = 0; col < RX * S; ++col) {
        if (col >= oxEnd) break;
        y[rowStart + col] = activate(acc[c * OUT_BLOCK + row * RX * S + col] + b, ACT);
      }
#endif
    }
  }
}
