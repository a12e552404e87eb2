#version 450
// 2-D convolution, PyTorch nn.Conv2d semantics (NCHW, zero padding, no dilation/groups):
// y[n][co][oy][ox] = act(b[co] + sum_{ci,ky,kx} x[n][ci][oy*S-padY+ky][ox*S-padX+kx] * w[co][ci][ky][kx]).
// Host side: engine/ops/conv2d.cpp.
//
// Written for llvmpipe first (see gemm.comp): x and w are uniform texel buffers, no shared
// memory, and each invocation owns a register block of RC output channels x RY rows x RX
// consecutive columns. Consecutive invocations along x take consecutive column blocks.
// Per group of G input channels an invocation loads the input tile its block needs once
// (zero outside the image), then for each of its RC channels fetches the G*KH*KW weights
// (contiguous in PyTorch's [Cout, Cin, kh, kw] layout; RGBA texels when aligned) and
// accumulates G*KH*KW*RY*RX products. The kernel shape and stride are specialization
// constants so every index into the tile is a compile-time constant.
// Measured on llvmpipe, 2 threads: 3x3, 64 -> 64 channels, 128x128, RC 16 x RY 2 x RX 8:
// about 21 ms (57 GFLOPS); reading x as RGBA texels instead of R saves about 25%.
//
// W_QUANT: w is a block-quantized kernel (q8 / q4 by W_BITS, shaders/quant.glsl): the matrix
// [Cout, Cin*KH*KW], each row its code words then its scales, dequantized per RGBA texel of 4
// weights as the rows are read (TEXEL_W is 4: the host quantizes only rows of whole blocks of 32).
//
// SHARED_WEIGHTS (the conv2d_sw_* variants, llvmpipe): the workgroup is one subgroup of LANES
// invocations, all of one block of output channels, so the RC x G*KH*KW weights of a step are
// the same in every lane. On llvmpipe each texel fetch is a call that spills the accumulators,
// and a fetch whose address is the same in every lane costs a full gather all the same: lane l
// fetches the block's weight texels l, LANES + l, ... and every lane takes a texel from its
// lane by a shuffle, so one fetch serves LANES texels (as gemm.comp's SHARED_COLUMNS does).
// Every lane stays to the end (the shuffles read all of them); lanes past the plane store nothing.
//! variant conv2d_f32 OUT4=0 W_QUANT=0
//! variant conv2d_f32_out4 OUT4=1 W_QUANT=0
//! variant conv2d_q_f32 OUT4=0 W_QUANT=1
//! variant conv2d_q_f32_out4 OUT4=1 W_QUANT=1
//! variant conv2d_sw_f32 OUT4=0 W_QUANT=0 SHARED_WEIGHTS=1
//! variant conv2d_sw_f32_out4 OUT4=1 W_QUANT=0 SHARED_WEIGHTS=1
#extension GL_GOOGLE_include_directive : require
#ifndef SHARED_WEIGHTS
#define SHARED_WEIGHTS 0
#endif
#if SHARED_WEIGHTS
#extension GL_KHR_shader_subgroup_shuffle : require
#endif
#include "common.glsl"
#include "quant.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const int KH = 3;
layout(constant_id = 4) const int KW = 3;
layout(constant_id = 5) const int STRIDE = 1;
layout(constant_id = 6) const int RC = 8;          // output channels per invocation
layout(constant_id = 7) const int RY = 2;          // output rows per invocation
layout(constant_id = 8) const int RX = 8;          // consecutive output columns per invocation
layout(constant_id = 9) const int G = 4;           // input channels per step (Cin is a multiple)
layout(constant_id = 10) const int TEXEL_W = 4;    // weights per texel: 4 (RGBA) or 1 (R)
layout(constant_id = 11) const int ACT = ACT_NONE;
layout(constant_id = 12) const bool HAS_BIAS = false;
// TEXEL_X = 4: x is read as RGBA texels of 4 consecutive columns (W, RX*STRIDE and the
// binding's start are multiples of 4); the tile starts SHIFT = (-padX) mod 4 columns into
// its first texel. TEXEL_X = 1: R texels, one column each.
layout(constant_id = 13) const int TEXEL_X = 1;
layout(constant_id = 14) const int SHIFT = 0;
// FLAT: invocations along x walk the RY x RX output blocks of a plane row-major across block
// rows (workgroups of localX x 1), so a small plane (32x32: 4 column blocks) still fills all
// SIMD lanes of a CPU device; otherwise x and y index column and row blocks (2-D workgroup
// tiles, which GPUs want for cache locality).
layout(constant_id = 15) const bool FLAT = false;
layout(constant_id = 16) const int W_BITS = 8;  // W_QUANT: 8 (q8) or 4 (q4)
layout(constant_id = 17) const int LANES = 8;   // SHARED_WEIGHTS: the workgroup's x size, one full subgroup

TEXEL_INPUT(0, X, TEXEL_X)     // TEXEL_X texels
#if W_QUANT
QUANT_INPUT(1, W)              // R32_UINT words of whole rows (quant.glsl)
#else
TEXEL_INPUT(1, W, TEXEL_W)     // TEXEL_W texels
#endif
TEXEL_INPUT(2, BIAS, 1)  // R texels; bound to w when HAS_BIAS is false
// OUT4: y is written as whole vec4s, RX/4 per output row of the block (the host guarantees
// RX, Wo and outBase multiples of 4). llvmpipe scatters a store whose address is not
// uniform lane by lane, so one vec4 store costs about what one float store does: with few
// input channels per output the stores, not the multiply-adds, bound the kernel.
#if OUT4
layout(binding = 3) writeonly buffer Y { vec4 y[]; };
#else
layout(binding = 3) writeonly buffer Y { float y[]; };
#endif

layout(push_constant) uniform Push {
  int Cin, H, W;
  int Cout, Ho, Wo;
  int padY, padX;
  int coBlocks;   // ceil(Cout / RC)
  int zBase;      // first (image, channel block) unit of this dispatch
  int inBase, wBase, biasBase;  // element of x, w, bias at texel 0 of X, W, BIAS (W_QUANT:
                                 // wBase is the word of w's first row at word 0 of W)
  int outBase;                   // element of the output tensor at y[0]
} p;

const int TR = (RY - 1) * STRIDE + KH;  // input tile rows
const int TC = (RX - 1) * STRIDE + KW;  // input tile columns
const int KK = KH * KW;
const int TT = (SHIFT + TC + 3) / 4;    // RGBA texels per tile row (TEXEL_X = 4)

void main() {
  int bx = int(gl_GlobalInvocationID.x), by = int(gl_GlobalInvocationID.y);
  if (FLAT) {
    const int colBlocks = (p.Wo + RX - 1) / RX;
    by = bx / colBlocks;
    bx -= by * colBlocks;
  }
  const int ox0 = bx * RX;
  const int oy0 = by * RY;
  // Past the plane: tile reads are clamped in bounds, and nothing is stored.
  const bool inPlane = ox0 < p.Wo && oy0 < p.Ho;
  if (SHARED_WEIGHTS == 0 && !inPlane) return;
  const int unit = p.zBase + int(gl_GlobalInvocationID.z);
  const int n = unit / p.coBlocks;
  const int co0 = (unit - n * p.coBlocks) * RC;

  // Tile geometry, the same for every input channel. Reads outside the image fetch an
  // in-bounds element and are replaced by zero.
  int rowOff[TR];
  bool rowIn[TR];
  [[unroll]] for (int r = 0; r < TR; ++r) {
    const int iy = oy0 * STRIDE - p.padY + r;
    rowIn[r] = iy >= 0 && iy < p.H;
    rowOff[r] = clamp(iy, 0, p.H - 1) * p.W;
  }
  int colOff[TC];
  bool colIn[TC];
  [[unroll]] for (int c = 0; c < TC; ++c) {
    const int ix = ox0 * STRIDE - p.padX + c;
    colIn[c] = ix >= 0 && ix < p.W;
    colOff[c] = clamp(ix, 0, p.W - 1);
  }
  // With RGBA texels: texel t of a tile row holds columns ox0*STRIDE - padX - SHIFT + 4t + 0..3.
  int texOff[TT];
  bool texIn[TT];
  [[unroll]] for (int t = 0; t < TT; ++t) {
    const int tx = (ox0 * STRIDE - p.padX - SHIFT) / 4 + t;  // numerator is a multiple of 4
    texIn[t] = tx >= 0 && tx < p.W / 4;
    texOff[t] = clamp(tx, 0, p.W / 4 - 1);
  }
  // First weight of each channel of the block (channels past Cout repeat the last one); with
  // W_QUANT the first word of its row (a row: Cin*KK/4 texels of codes and scales).
  const int kTexels = p.Cin * KK / 4;
  const int rowWords = QUANT_ROW_WORDS(kTexels);
  int wOff[RC];
  [[unroll]] for (int c = 0; c < RC; ++c)
    wOff[c] = W_QUANT != 0 ? min(co0 + c, p.Cout - 1) * rowWords - p.wBase
                           : min(co0 + c, p.Cout - 1) * p.Cin * KK - p.wBase;

  float acc[RC * RY * RX];
  [[unroll]] for (int i = 0; i < RC * RY * RX; ++i) acc[i] = 0.0;

  const int plane = p.H * p.W;
  int xOff = n * p.Cin * plane - p.inBase;
  for (int ci0 = 0; ci0 < p.Cin; ci0 += G) {
    float tile[G * TR * TC];
    [[unroll]] for (int g = 0; g < G; ++g) {
      [[unroll]] for (int r = 0; r < TR; ++r) {
        if (r % STRIDE >= KH) continue;  // rows no tap reads (KH < STRIDE)
        if (TEXEL_X == 4) {
          const int rowTexel = (xOff + rowOff[r]) / 4;
          [[unroll]] for (int t = 0; t < TT; ++t) {
            const vec4 v = fetch_X(rowTexel + texOff[t]);
            [[unroll]] for (int j = 0; j < 4; ++j) {
              const int c = 4 * t + j - SHIFT;
              if (c >= 0 && c < TC) tile[(g * TR + r) * TC + c] = rowIn[r] && texIn[t] ? v[j] : 0.0;
            }
          }
        } else {
          [[unroll]] for (int c = 0; c < TC; ++c) {
            if (c % STRIDE >= KW) continue;
            const float v = fetch_X(xOff + rowOff[r] + colOff[c]).x;
            tile[(g * TR + r) * TC + c] = rowIn[r] && colIn[c] ? v : 0.0;
          }
        }
      }
      xOff += plane;
    }
#if SHARED_WEIGHTS
    // The step's weight texels of the whole block (GT a channel, channel-major), LANES apart
    // in each lane's share; past the block's last texel a lane re-reads it (never used).
    const int GT = G * KK / 4;
    const int WT = (RC * GT + LANES - 1) / LANES;
    vec4 wt[WT];
    [[unroll]] for (int j = 0; j < WT; ++j) {
      const int t = min(j * LANES + int(gl_SubgroupInvocationID), RC * GT - 1);
      const int c = t / GT;
      wt[j] = fetch_W((min(co0 + c, p.Cout - 1) * p.Cin * KK - p.wBase + ci0 * KK) / 4 + t - c * GT);
    }
#endif
    [[unroll]] for (int c = 0; c < RC; ++c) {
      float wv[G * KK];
#if SHARED_WEIGHTS
      [[unroll]] for (int t = 0; t < G * KK / 4; ++t) {
        const int s = c * (G * KK / 4) + t;
        const vec4 q = subgroupShuffle(wt[s / LANES], s % LANES);
        wv[4 * t] = q.x;
        wv[4 * t + 1] = q.y;
        wv[4 * t + 2] = q.z;
        wv[4 * t + 3] = q.w;
      }
#else
      if (TEXEL_W == 4) {
#if W_QUANT
        const int t0 = ci0 * KK / 4;  // texel of the row
#else
        const int t0 = (wOff[c] + ci0 * KK) / 4;
#endif
        [[unroll]] for (int t = 0; t < G * KK / 4; ++t) {
#if W_QUANT
          const vec4 q = fetchq_W(wOff[c], t0 + t, kTexels);
#else
          const vec4 q = fetch_W(t0 + t);
#endif
          wv[4 * t] = q.x;
          wv[4 * t + 1] = q.y;
          wv[4 * t + 2] = q.z;
          wv[4 * t + 3] = q.w;
        }
      } else {
#if !W_QUANT
        [[unroll]] for (int t = 0; t < G * KK; ++t) wv[t] = fetch_W(wOff[c] + ci0 * KK + t).x;
#endif
      }
#endif
      [[unroll]] for (int g = 0; g < G; ++g)
        [[unroll]] for (int ky = 0; ky < KH; ++ky)
          [[unroll]] for (int kx = 0; kx < KW; ++kx) {
            const float w = wv[(g * KH + ky) * KW + kx];
            [[unroll]] for (int py = 0; py < RY; ++py)
              [[unroll]] for (int px = 0; px < RX; ++px) {
                const int i = (c * RY + py) * RX + px;
                acc[i] = fma(w, tile[(g * TR + py * STRIDE + ky) * TC + px * STRIDE + kx], acc[i]);
              }
          }
    }
  }

  if (!inPlane) return;
  [[unroll]] for (int c = 0; c < RC; ++c) {
    const int co = co0 + c;
    if (co >= p.Cout) break;
    const float b = HAS_BIAS ? fetch_BIAS(co - p.biasBase).x : 0.0;
    [[unroll]] for (int py = 0; py < RY; ++py) {
      const int oy = oy0 + py;
      if (oy >= p.Ho) break;
      const int rowStart = ((n * p.Cout + co) * p.Ho + oy) * p.Wo - p.outBase;
#if OUT4
      [[unroll]] for (int q = 0; q < RX / 4; ++q) {
        if (ox0 + 4 * q >= p.Wo) break;
        const int i = (c * RY + py) * RX + 4 * q;
        y[(rowStart + ox0) / 4 + q] = vec4(activate(acc[i] + b, ACT), activate(acc[i + 1] + b, ACT),
                                           activate(acc[i + 2] + b, ACT), activate(acc[i + 3] + b, ACT));
      }
#else
      [[unroll]] for (int px = 0; px < RX; ++px) {
        if (ox0 + px >= p.Wo) break;
        y[rowStart + ox0 + px] = activate(acc[(c * RY + py) * RX + px] + b, ACT);
      }
#endif
    }
  }
}
