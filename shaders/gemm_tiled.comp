#version 450
// GEMM for GPUs: workgroup tiles staged in shared memory. Host side: engine/ops/linear.cpp
// (linear layers) and engine/ops/conv2d.cpp (convolution as an implicit GEMM, CONV=1).
//   y[b][m][n] = act(sum_k A[b][m][k] * W[b][n][k] + bias[n])
// A workgroup computes a BM x BN tile of y: per step of BK it copies the BM x BK slice of A
// and the BN x BK slice of W into shared memory (k-major, so the compute loop reads runs of
// consecutive rows and columns), then each of its (BM/TM)*(BN/TN) invocations accumulates a
// TM x TN register block from them (PREFETCH, INTERLEAVE: below). Tile sizes are
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
// (16: gemm_epilogue.glsl's SCALED)
layout(constant_id = 17) const bool PREFETCH = true;     // the next k step fetched while this one computes
layout(constant_id = 18) const bool INTERLEAVE = true;   // register blocks in runs of 4 spread over the tile
// CONV of a 1x1 kernel, stride 1, no padding, a multiple of 4 pixels an image: a plain GEMM of
// the weight and the image's [Cin, H*W] matrix, whose tile rows are read as RGBA texels of 4
// pixels (x bound so) instead of one value each through the im2col arithmetic.
layout(constant_id = 19) const bool POINTWISE = false;

TEXEL_INPUT(0, X, (CONV == 1 ? (POINTWISE ? 4 : 1) : TEXEL_K))  // A (CONV: the image, R texels; POINTWISE RGBA)
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
  return 0.0;  // not used: the linear path fetches whole texels (fetchTiles)
#endif
}

// The tiles' global reads and shared-memory writes are apart, so that with PREFETCH the next k
// step's texels are fetched into registers (aNext, wNext) while this step is computed (ncnn's
// technique): a GPU then overlaps global latency with arithmetic instead of waiting at each step.
// Invocation t takes elements t, t + WG, ... of each tile, consecutive invocations along a row
// of texels (CONV: consecutive output pixels, neighbouring image columns).
#if CONV
// values of the im2col view (POINTWISE: texels of 4 pixels of a channel)
const int A_FETCHES = POINTWISE ? (BM / 4 * BK + WG - 1) / WG : (BM * BK + WG - 1) / WG;
vec4 aNext[A_FETCHES];
#else
const int A_FETCHES = (BM * (BK / TEXEL_K) + WG - 1) / WG;  // texels of TEXEL_K consecutive k
vec4 aNext[A_FETCHES];
#endif
const int W_FETCHES = (BN * (BK / TEXEL_K) + WG - 1) / WG;
vec4 wNext[W_FETCHES];

// Fetches the k0.. k0+BK slices of A (rows m0..) and W (rows n0..) into aNext and wNext.
void fetchTiles(int img, int m0, int n0, int k0) {
  const int t = int(gl_LocalInvocationIndex);
#if CONV
  [[unroll]] for (int f = 0; f < A_FETCHES; ++f) {
    const int i = t + f * WG;
    if (POINTWISE) {  // a whole texel is inside the image or outside it (H*W a multiple of 4)
      const int r = (i % (BM / 4)) * 4, kk = i / (BM / 4);
      const int m = m0 + r, k = k0 + kk;
      aNext[f] = i < BM / 4 * BK && m < rowsM() && k < p.Cin ? fetch_X((p.inBase + (img * p.Cin + k) * rowsM() + m) / 4)
                                                              : vec4(0.0);
    } else {
      const int r = i % BM, kk = i / BM;
      const int m = m0 + r;
      aNext[f].x = i < BM * BK && m < rowsM() ? loadA(img, m, k0 + kk) : 0.0;
    }
  }
#else
  const int texelsPerRow = BK / TEXEL_K;
  const int kt0 = k0 / TEXEL_K;
  [[unroll]] for (int f = 0; f < A_FETCHES; ++f) {
    const int i = t + f * WG, r = i / texelsPerRow, kt = i - r * texelsPerRow;
    const int m = m0 + r;
    aNext[f] = i < BM * texelsPerRow && m < p.M && kt0 + kt < p.K ? fetch_X(img * p.xBatch + m * p.ldx + kt0 + kt) : vec4(0.0);
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
  [[unroll]] for (int f = 0; f < W_FETCHES; ++f) {
    const int i = t + f * WG, r = i / wTexelsPerRow, kt = i - r * wTexelsPerRow;
    const int n = n0 + r;
    vec4 v = vec4(0.0);
#if W_QUANT
    if (i < BN * wTexelsPerRow && n < colsN() && wk0 + kt < kTexels) v = fetchq_W(wBase + wBatch + n * wLd, wk0 + kt, kTexels);
#else
    if (i < BN * wTexelsPerRow && n < colsN() && wk0 + kt < kTexels) v = fetch_W(wBase + wBatch + n * wLd + wk0 + kt);
#endif
    wNext[f] = v;
  }
}

// Writes aNext and wNext into the shared tiles (k-major).
void storeTiles() {
  const int t = int(gl_LocalInvocationIndex);
#if CONV
  [[unroll]] for (int f = 0; f < A_FETCHES; ++f) {
    const int i = t + f * WG;
    if (POINTWISE) {
      const int r = (i % (BM / 4)) * 4, kk = i / (BM / 4);
      if (i < BM / 4 * BK)
        [[unroll]] for (int c = 0; c < 4; ++c) tileA[kk * AS + r + c] = TO_TILE(aNext[f][c]);
    } else if (i < BM * BK) {
      tileA[(i / BM) * AS + i % BM] = TO_TILE(aNext[f].x);
    }
  }
#else
  const int texelsPerRow = BK / TEXEL_K;
  [[unroll]] for (int f = 0; f < A_FETCHES; ++f) {
    const int i = t + f * WG, r = i / texelsPerRow, kt = i - r * texelsPerRow;
    if (i < BM * texelsPerRow)
      [[unroll]] for (int c = 0; c < TEXEL_K; ++c) tileA[(kt * TEXEL_K + c) * AS + r] = TO_TILE(aNext[f][c]);
  }
#endif
  const int wTexelsPerRow = BK / TEXEL_K;
  [[unroll]] for (int f = 0; f < W_FETCHES; ++f) {
    const int i = t + f * WG, r = i / wTexelsPerRow, kt = i - r * wTexelsPerRow;
    if (i < BN * wTexelsPerRow)
      [[unroll]] for (int c = 0; c < TEXEL_K; ++c) tileW[(kt * TEXEL_K + c) * WS + r] = TO_TILE(wNext[f][c]);
  }
}

// The tile rows and columns of an invocation's register block: with INTERLEAVE (TM, TN multiples
// of 4) runs of 4 spread over the tile, BM / (TM / 4) rows apart (ggml-vulkan's sub-tiles), so
// the invocations of a warp read neighbouring 16-byte runs of a shared row and store neighbouring
// runs of y; else TM (TN) consecutive ones.
int rowOf(int tRow, int i) {
  return INTERLEAVE && TM % 4 == 0 ? (i / 4) * (BM / (TM / 4)) + tRow * 4 + i % 4 : tRow * TM + i;
}
int colOf(int tCol, int j) {
  return INTERLEAVE && TN % 4 == 0 ? (j / 4) * (BN / (TN / 4)) + tCol * 4 + j % 4 : tCol * TN + j;
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
#if CONV
  // y is NCHW (a column of the GEMM is a plane): neighbouring invocations take neighbouring
  // output pixels, so their stores are neighbouring addresses.
  const int tCol = t / (BM / TM), tRow = t - tCol * (BM / TM);
#else
  const int tRow = t / (BN / TN), tCol = t - tRow * (BN / TN);
#endif

  float acc[TM * TN];
  [[unroll]] for (int i = 0; i < TM * TN; ++i) acc[i] = 0.0;

  const int K = depthK();
  fetchTiles(img, m0, n0, 0);
  for (int k0 = 0; k0 < K; k0 += BK) {
    storeTiles();
    barrier();
    const bool more = k0 + BK < K;
    if (PREFETCH && more) fetchTiles(img, m0, n0, k0 + BK);
#if FP16_MATH
    for (int kk = 0; kk < BK; kk += 4) {
      f16vec4 a[TM], b[TN];
      [[unroll]] for (int i = 0; i < TM; ++i) {
        const int r = rowOf(tRow, i);
        a[i] = f16vec4(tileA[kk * AS + r], tileA[(kk + 1) * AS + r], tileA[(kk + 2) * AS + r], tileA[(kk + 3) * AS + r]);
      }
      [[unroll]] for (int j = 0; j < TN; ++j) {
        const int c = colOf(tCol, j);
        b[j] = f16vec4(tileW[kk * WS + c], tileW[(kk + 1) * WS + c], tileW[(kk + 2) * WS + c], tileW[(kk + 3) * WS + c]);
      }
      [[unroll]] for (int i = 0; i < TM; ++i)
        [[unroll]] for (int j = 0; j < TN; ++j)
          acc[i * TN + j] += clamp(float(dot(a[i], b[j])), -65504.0, 65504.0);
    }
#else
    for (int kk = 0; kk < BK; ++kk) {
      float a[TM], b[TN];
      [[unroll]] for (int i = 0; i < TM; ++i) a[i] = tileA[kk * AS + rowOf(tRow, i)];
      [[unroll]] for (int j = 0; j < TN; ++j) b[j] = tileW[kk * WS + colOf(tCol, j)];
      [[unroll]] for (int i = 0; i < TM; ++i)
        [[unroll]] for (int j = 0; j < TN; ++j) acc[i * TN + j] = fma(a[i], b[j], acc[i * TN + j]);
    }
#endif
    barrier();
    if (!PREFETCH && more) fetchTiles(img, m0, n0, k0 + BK);
  }

  [[unroll]] for (int i = 0; i < TM; ++i) {
    const int m = m0 + rowOf(tRow, i);
    if (m >= rowsM()) break;
    [[unroll]] for (int j = 0; j < TN; ++j) {
      const int n = n0 + colOf(tCol, j);
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
