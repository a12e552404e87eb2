#version 450
// GEMM for GPUs: workgroup tiles staged in shared memory. Host side: engine/ops/linear.cpp
// (linear layers) and engine/ops/conv2d.cpp (convolution as an implicit GEMM, CONV=1).
//   y[b][m][n] = act(sum_k A[b][m][k] * W[b][n][k] + bias[n])
// A workgroup computes a BM x BN tile of y: per step of BK it copies the BM x BK slice of A
// and the BN x BK slice of W into shared memory (k-major, so the compute loop reads TM
// consecutive rows and TN consecutive columns), then each of its (BM/TM)*(BN/TN)
// invocations accumulates a TM x TN register block from them. Tile sizes are
// specialization constants (engine/kernel_plan.cpp chooses them per device). This is the GPU
// family; the llvmpipe family is gemm.comp (register blocks, no shared memory: shared memory
// is a lane loop plus a coroutine switch per barrier there).
//
// Inputs come through the same uniform texel buffers as gemm.comp (fp16 weights are
// converted by the sampler, tensors above a storage binding's range need no split).
// CONV: A is the im2col view of an NCHW image, built while loading the tile (m = output
//   pixel oy*Wo+ox, k = ci*KH*KW + ky*KW + kx, zero outside the image), W the [Cout, Cin*KH*KW]
//   PyTorch weight, and y is written NCHW (y[n][m] at n*Ho*Wo + m). Workgroup layers are work
//   units (image, block of output channels), so an output larger than one binding is split.
// FP16_MATH: the tiles are kept in fp16 and each run of 4 k is a fp16 dot product (the
//   device's packed fp16 arithmetic), added into an fp32 accumulator: fp16 rounding of the
//   inputs and of 4-term partial sums, never of the running sum. A partial beyond fp16's range
//   saturates at +-65504 rather than becoming infinite.
// W_QUANT: W is a block-quantized matrix (q8 / q4 by W_BITS, shaders/quant.glsl; a convolution
//   kernel as its [Cout, Cin*KH*KW]), read as 32-bit words and dequantized a texel of 4 k at a
//   time while its tile is copied into shared memory: the compute loop is the f32 one. Rows are
//   whole blocks of 32 (TEXEL_K 4); ldw (CONV: the row length in words, from wRow) is in words.
//! variant gemm_tiled_f32 OUT_F16=0 FP16_MATH=0 CONV=0 W_QUANT=0
//! variant gemm_tiled_f16out OUT_F16=1 FP16_MATH=0 CONV=0 W_QUANT=0
//! variant gemm_tiled_h16 OUT_F16=0 FP16_MATH=1 CONV=0 W_QUANT=0
//! variant gemm_tiled_h16_f16out OUT_F16=1 FP16_MATH=1 CONV=0 W_QUANT=0
//! variant conv2d_tiled_f32 OUT_F16=0 FP16_MATH=0 CONV=1 W_QUANT=0
//! variant gemm_tiled_q_f32 OUT_F16=0 FP16_MATH=0 CONV=0 W_QUANT=1
//! variant gemm_tiled_q_f16out OUT_F16=1 FP16_MATH=0 CONV=0 W_QUANT=1
//! variant conv2d_tiled_q_f32 OUT_F16=0 FP16_MATH=0 CONV=1 W_QUANT=1
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"
#include "quant.glsl"
#if FP16_MATH
#extension GL_EXT_shader_explicit_arithmetic_types_float16 : require
#define TILE_T float16_t
#define TILE_ZERO float16_t(0.0)
#define TO_TILE(v) float16_t(clamp((v), -65504.0, 65504.0))
#else
#define TILE_T float
#define TILE_ZERO 0.0
#define TO_TILE(v) (v)
#endif

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const int BM = 64;        // rows of y per workgroup
layout(constant_id = 4) const int BN = 64;        // columns of y per workgroup
layout(constant_id = 5) const int BK = 16;        // k per shared-memory step (multiple of 4)
layout(constant_id = 6) const int TM = 4;         // rows per invocation (BM / TM * BN / TN = workgroup size)
layout(constant_id = 7) const int TN = 4;         // columns per invocation
layout(constant_id = 8) const int TEXEL_K = 4;    // W (and A unless CONV): k values per texel, 4 or 1
layout(constant_id = 9) const int ACT = ACT_NONE;
layout(constant_id = 10) const bool HAS_BIAS = false;
layout(constant_id = 11) const int KH = 1;        // CONV: kernel height, width, stride
layout(constant_id = 12) const int KW = 1;
layout(constant_id = 13) const int STRIDE = 1;
layout(constant_id = 14) const int W_BITS = 8;    // W_QUANT: 8 (q8) or 4 (q4)
layout(constant_id = 15) const bool ACCUMULATE = false;  // y += the result (a fused residual add)

TEXEL_INPUT(0, X, (CONV == 1 ? 1 : TEXEL_K))     // A (CONV: the image, R texels)
#if W_QUANT
QUANT_INPUT(1, W)
#else
TEXEL_INPUT(1, W, TEXEL_K)
#endif
#include "gemm_epilogue.glsl"  // the bias binding (2), SCALED
layout(binding = 3) buffer Y { OUT_T y[]; };  // read back only with ACCUMULATE

#if CONV
layout(push_constant) uniform Push {
  int Cin, H, W, Cout, Ho, Wo, padY, padX;
  int wRow;                             // texels per weight row (Cin*KH*KW / TEXEL_K)
  // Where element 0 of x, w (in texels), bias and y is in its binding (negative when the
  // binding starts later: a chunk of images).
  int inBase, wBase, biasBase, outBase;
  int blocks, blockChannels, zBase;     // channel blocks per image and their size; first unit
} p;
#else
layout(push_constant) uniform Push {
  int M, N, K;       // K in texels
  int ldx, ldw;      // row strides of x and w in texels
  int ldy;           // row stride of y in elements
  int xBatch, wBatch, yBatch;  // batch strides (texels, texels, elements); wBatch 0 shares w
} p;
#endif

const int WG = (BM / TM) * (BN / TN);
// Padding per k row: the copy's transposed stores do not all hit one bank, and rows stay
// 16-byte aligned, so the compute loop's TM (TN) consecutive reads can be one vector load.
#if FP16_MATH
const int PAD = 8;
#else
const int PAD = 4;
#endif
const int AS = BM + PAD, WS = BN + PAD;
shared TILE_T tileA[BK * AS];
shared TILE_T tileW[BK * WS];

// CONV: the unit's output channels are [chan0, chanEnd).
int chan0 = 0, chanEnd = 0;
#if CONV
int rowsM() { return p.Ho * p.Wo; }
int colsN() { return chanEnd; }
int depthK() { return p.Cin * KH * KW; }  // in values
#else
int rowsM() { return p.M; }
int colsN() { return p.N; }
int depthK() { return p.K * TEXEL_K; }
#endif

// One value of A (row m < M, any k: zero past K).
float loadA(int img, int m, int k) {
#if CONV
  if (k >= depthK()) return 0.0;
  const int ci = k / (KH * KW), r = k - ci * (KH * KW);
  const int ky = r / KW, kx = r - ky * KW;
  const int oy = m / p.Wo, ox = m - oy * p.Wo;
  const int iy = oy * STRIDE - p.padY + ky, ix = ox * STRIDE - p.padX + kx;
  if (iy < 0 || iy >= p.H || ix < 0 || ix >= p.W) return 0.0;
  return fetch_X(p.inBase + (img * p.Cin + ci) * p.H * p.W + iy * p.W + ix).x;
#else
  return 0.0;  // not used: the linear path copies whole texels (copyTiles)
#endif
}

// Copies the k0.. k0+BK slices of A (rows m0..) and W (rows n0..) into shared memory.
void copyTiles(int img, int m0, int n0, int k0) {
  const int t = int(gl_LocalInvocationIndex);
#if CONV
  // A: consecutive invocations take consecutive rows (output pixels: neighbouring image
  // columns), so the gather reads adjacent addresses.
  for (int i = t; i < BM * BK; i += WG) {
    const int r = i % BM, kk = i / BM;
    const int m = m0 + r;
    tileA[kk * AS + r] = m < rowsM() ? TO_TILE(loadA(img, m, k0 + kk)) : TILE_ZERO;
  }
#else
  // A and W: texels of TEXEL_K consecutive k; consecutive invocations read along a row.
  const int texelsPerRow = BK / TEXEL_K;
  const int kt0 = k0 / TEXEL_K;
  for (int i = t; i < BM * texelsPerRow; i += WG) {
    const int r = i / texelsPerRow, kt = i - r * texelsPerRow;
    const int m = m0 + r;
    vec4 v = vec4(0.0);
    if (m < p.M && kt0 + kt < p.K) v = fetch_X(img * p.xBatch + m * p.ldx + kt0 + kt);
    [[unroll]] for (int c = 0; c < TEXEL_K; ++c) tileA[(kt * TEXEL_K + c) * AS + r] = TO_TILE(v[c]);
  }
#endif
#if CONV && W_QUANT
  // a quantized row: its kTexels / (W_BITS == 8 ? 1 : 2) code words, then one scale a block
  const int kTexels = p.wRow, wBatch = 0, wBase = p.wBase;
  const int wLd = QUANT_ROW_WORDS(kTexels);
#elif CONV
  const int wBatch = 0, wLd = p.wRow, wBase = p.wBase, kTexels = p.wRow;
#else
  const int wBatch = img * p.wBatch, wLd = p.ldw, wBase = 0, kTexels = p.K;
#endif
  const int wTexelsPerRow = BK / TEXEL_K;
  const int wk0 = k0 / TEXEL_K;
  for (int i = t; i < BN * wTexelsPerRow; i += WG) {
    const int r = i / wTexelsPerRow, kt = i - r * wTexelsPerRow;
    const int n = n0 + r;
    vec4 v = vec4(0.0);
#if W_QUANT
    if (n < colsN() && wk0 + kt < kTexels) v = fetchq_W(wBase + wBatch + n * wLd, wk0 + kt, kTexels);
#else
    if (n < colsN() && wk0 + kt < kTexels) v = fetch_W(wBase + wBatch + n * wLd + wk0 + kt);
#endif
    [[unroll]] for (int c = 0; c < TEXEL_K; ++c) tileW[(kt * TEXEL_K + c) * WS + r] = TO_TILE(v[c]);
  }
}

void main() {
#if CONV
  const int unit = p.zBase + int(gl_WorkGroupID.z);
  const int img = unit / p.blocks;
  chan0 = (unit - img * p.blocks) * p.blockChannels;
  chanEnd = min(p.Cout, chan0 + p.blockChannels);
  const int n0 = chan0 + int(gl_WorkGroupID.y) * BN;
#else
  const int img = int(gl_WorkGroupID.z);
  const int n0 = int(gl_WorkGroupID.y) * BN;
#endif
  const int m0 = int(gl_WorkGroupID.x) * BM;
  const int t = int(gl_LocalInvocationIndex);
  const int tRow = t / (BN / TN), tCol = t - tRow * (BN / TN);

  float acc[TM * TN];
  [[unroll]] for (int i = 0; i < TM * TN; ++i) acc[i] = 0.0;

  const int K = depthK();
  for (int k0 = 0; k0 < K; k0 += BK) {
    copyTiles(img, m0, n0, k0);
    barrier();
#if FP16_MATH
    for (int kk = 0; kk < BK; kk += 4) {
      f16vec4 a[TM], b[TN];
      [[unroll]] for (int i = 0; i < TM; ++i) {
        const int r = tRow * TM + i;
        a[i] = f16vec4(tileA[kk * AS + r], tileA[(kk + 1) * AS + r], tileA[(kk + 2) * AS + r], tileA[(kk + 3) * AS + r]);
      }
      [[unroll]] for (int j = 0; j < TN; ++j) {
        const int c = tCol * TN + j;
        b[j] = f16vec4(tileW[kk * WS + c], tileW[(kk + 1) * WS + c], tileW[(kk + 2) * WS + c], tileW[(kk + 3) * WS + c]);
      }
      [[unroll]] for (int i = 0; i < TM; ++i)
        [[unroll]] for (int j = 0; j < TN; ++j)
          acc[i * TN + j] += clamp(float(dot(a[i], b[j])), -65504.0, 65504.0);
    }
#else
    for (int kk = 0; kk < BK; ++kk) {
      float a[TM], b[TN];
      [[unroll]] for (int i = 0; i < TM; ++i) a[i] = tileA[kk * AS + tRow * TM + i];
      [[unroll]] for (int j = 0; j < TN; ++j) b[j] = tileW[kk * WS + tCol * TN + j];
      [[unroll]] for (int i = 0; i < TM; ++i)
        [[unroll]] for (int j = 0; j < TN; ++j) acc[i * TN + j] = fma(a[i], b[j], acc[i * TN + j]);
    }
#endif
    barrier();
  }

  [[unroll]] for (int i = 0; i < TM; ++i) {
    const int m = m0 + tRow * TM + i;
    if (m >= rowsM()) break;
    [[unroll]] for (int j = 0; j < TN; ++j) {
      const int n = n0 + tCol * TN + j;
      if (n >= colsN()) break;
      float v = acc[i * TN + j];
#if CONV
      if (HAS_BIAS) v += fetch_BIAS(p.biasBase + n).x;
      y[p.outBase + (img * p.Cout + n) * rowsM() + m] = TO_OUT(activate(v, ACT));
#else
      STORE_OUT(img * p.yBatch + m * p.ldy + n, gemm_epilogue(v, n));
#endif
    }
  }
}
