#version 450
// Linear layer as GEMM: y[b][m][n] = act(sum_k x[b][m][k] * w[b][n][k] + bias[n]).
// Host side: engine/ops/linear.cpp.
//
// x and w are read through uniform texel buffers (RGBA texels = 4 consecutive k, or R
// texels when K is not a multiple of 4): llvmpipe turns texel fetches into branch-free
// gathers, about twice as fast as storage-buffer loads whose address is not uniform.
// Each invocation owns an RM x RN register block of outputs and no shared memory is used:
// on a CPU device the block is the cache-resident working set; on a GPU the host picks
// smaller blocks. Both x and w have k contiguous (PyTorch's out x in weight layout).
//
// W_QUANT: w is a block-quantized matrix (q8 / q4 by W_BITS, shaders/quant.glsl), read as
// 32-bit words and dequantized per texel; ldw is then the row stride in words.
//
// SHARED_COLUMNS (the gemm_sc_* variants): the workgroup is one subgroup of LANES invocations
// along m, and they share its RN columns. Lane l fetches the texels of columns l, LANES + l, ...
// and every lane takes a column's values from its lane by a shuffle, so one fetch serves LANES
// columns instead of one. On llvmpipe a texel fetch is a call to a gather routine, and the call
// spills every register (the accumulators included) around it: a fetch per column held the
// kernel at a third of what the driver's arithmetic reaches; sharing columns cut the calls a
// k texel from RM + RN to RM + RN / LANES (docs/first-run-and-kernels.md, "Kernel choice per
// device"). Host side picks it (engine/ops/linear.cpp, chooseGemmTiles) where the device has
// subgroup shuffles and full subgroups of that size.
//! variant gemm_f32 OUT_F16=0 W_QUANT=0
//! variant gemm_f16out OUT_F16=1 W_QUANT=0
//! variant gemm_q_f32 OUT_F16=0 W_QUANT=1
//! variant gemm_q_f16out OUT_F16=1 W_QUANT=1
//! variant gemm_sc_f32 OUT_F16=0 W_QUANT=0 SHARED_COLUMNS=1
//! variant gemm_sc_f16out OUT_F16=1 W_QUANT=0 SHARED_COLUMNS=1
//! variant gemm_sc_q_f32 OUT_F16=0 W_QUANT=1 SHARED_COLUMNS=1
//! variant gemm_sc_q_f16out OUT_F16=1 W_QUANT=1 SHARED_COLUMNS=1
#extension GL_GOOGLE_include_directive : require
#ifndef SHARED_COLUMNS
#define SHARED_COLUMNS 0
#endif
#if SHARED_COLUMNS
#extension GL_KHR_shader_subgroup_shuffle : require
#endif
#include "common.glsl"
#include "quant.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const int RM = 16;         // rows of y per invocation
layout(constant_id = 4) const int RN = 16;         // columns of y per invocation (SHARED_COLUMNS: a multiple of LANES)
layout(constant_id = 5) const int TEXEL_K = 4;     // k values per texel: 4 (RGBA) or 1 (R)
layout(constant_id = 6) const int ACT = ACT_NONE;  // fused epilogue activation
layout(constant_id = 7) const bool HAS_BIAS = false;
layout(constant_id = 8) const int KU = 2;          // k texels per loop iteration
layout(constant_id = 9) const int W_BITS = 8;      // W_QUANT: 8 (q8) or 4 (q4)
layout(constant_id = 10) const int LANES = 8;      // SHARED_COLUMNS: the workgroup's x size, one full subgroup
layout(constant_id = 11) const int GROUP_M = 0;    // workgroups walk the columns in groups of this many blocks of rows (0: as dispatched)
layout(constant_id = 15) const bool ACCUMULATE = false;  // y += the result (a fused residual add)

TEXEL_INPUT(0, X, TEXEL_K)
#if W_QUANT
QUANT_INPUT(1, W)
#define W_AT(row, kk) fetchq_W(row, kk, p.K)
#else
TEXEL_INPUT(1, W, TEXEL_K)
#define W_AT(row, kk) fetch_W((row) + (kk))
#endif
#include "gemm_epilogue.glsl"  // the bias binding (2), SCALED
layout(binding = 3) buffer Y { OUT_T y[]; };  // read back only with ACCUMULATE

layout(push_constant) uniform Push {
  int M, N, K;       // K in texels
  int ldx, ldw;      // row strides of x and w in texels
  int ldy;           // row stride of y in elements
  int xBatch, wBatch, yBatch;  // batch strides (texels, texels, elements); wBatch 0 shares w
} p;

// The workgroup's block of rows (x) and of columns (y). A CPU driver runs workgroups in the
// order of their index, x fastest: as dispatched, every block of columns then reads all of x
// again, and x of a large product does not stay in cache between them. With GROUP_M the index
// is remapped so that GROUP_M blocks of rows go through every block of columns together: their
// rows of x stay in cache, and w is read once per group.
ivec2 workgroupBlock() {
  if (GROUP_M <= 0) return ivec2(gl_WorkGroupID.xy);
  // unsigned: a grid of up to 65535 x 65535 workgroups (Vulkan's largest) numbers them in 32 bits
  const uint across = gl_NumWorkGroups.x, groupM = uint(GROUP_M);
  const uint index = gl_WorkGroupID.y * across + gl_WorkGroupID.x, perGroup = groupM * gl_NumWorkGroups.y;
  const uint group = index / perGroup, first = group * groupM, size = min(groupM, across - first);
  const uint i = index - group * perGroup;
  return ivec2(int(first + i % size), int(i / size));
}

void main() {
  const ivec2 block = workgroupBlock();
  const int m0 = (block.x * int(gl_WorkGroupSize.x) + int(gl_LocalInvocationID.x)) * RM;
  const int b = int(gl_GlobalInvocationID.z);
#if SHARED_COLUMNS
  // Every lane stays to the end, past the edges too: the shuffles need all of them.
  const int n0 = block.y * RN;
  const int WT = RN / LANES;  // column texels a lane fetches
  int wRow[WT];
  [[unroll]] for (int j = 0; j < WT; ++j)
    wRow[j] = b * p.wBatch + min(n0 + j * LANES + int(gl_SubgroupInvocationID), p.N - 1) * p.ldw;
#else
  const int n0 = (block.y * int(gl_WorkGroupSize.y) + int(gl_LocalInvocationID.y)) * RN;
  if (m0 >= p.M || n0 >= p.N) return;
  const int WT = RN;
  int wRow[WT];
  [[unroll]] for (int c = 0; c < RN; ++c) wRow[c] = b * p.wBatch + min(n0 + c, p.N - 1) * p.ldw;
#endif
  // Rows and columns past the edge re-read the last one (always in bounds); their results are dropped.
  int xRow[RM];
  [[unroll]] for (int r = 0; r < RM; ++r) xRow[r] = b * p.xBatch + min(m0 + r, p.M - 1) * p.ldx;

  float acc[RM * RN];
  [[unroll]] for (int i = 0; i < RM * RN; ++i) acc[i] = 0.0;

  // One k texel: every fetch first (RM x-texels, WT w-texels), then RN columns feeding RM fma
  // chains each.
#if SHARED_COLUMNS
#define COLUMN(c) subgroupShuffle(wt[(c) / LANES], (c) % LANES)
#else
#define COLUMN(c) wt[c]
#endif
#define GEMM_STEP(kk)                                                           \
  {                                                                             \
    vec4 a[RM];                                                                 \
    [[unroll]] for (int r = 0; r < RM; ++r) a[r] = fetch_X(xRow[r] + (kk));     \
    vec4 wt[WT];                                                                \
    [[unroll]] for (int j = 0; j < WT; ++j) wt[j] = W_AT(wRow[j], kk);          \
    [[unroll]] for (int c = 0; c < RN; ++c) {                                   \
      const vec4 w = COLUMN(c);                                                 \
      [[unroll]] for (int r = 0; r < RM; ++r) {                                 \
        float s = acc[r * RN + c];                                              \
        [[unroll]] for (int j = 0; j < TEXEL_K; ++j) s = fma(a[r][j], w[j], s); \
        acc[r * RN + c] = s;                                                    \
      }                                                                         \
    }                                                                           \
  }
  int k = 0;
  for (; k + KU <= p.K; k += KU) {
    [[unroll]] for (int u = 0; u < KU; ++u) GEMM_STEP(k + u)
  }
  for (; k < p.K; ++k) GEMM_STEP(k)

  [[unroll]] for (int r = 0; r < RM; ++r) {
    const int m = m0 + r;
    if (m >= p.M) break;
    [[unroll]] for (int c = 0; c < RN; ++c) {
      const int n = n0 + c;
      if (n >= p.N) break;
      float v = acc[r * RN + c];
      STORE_OUT(b * p.yBatch + m * p.ldy + n, gemm_epilogue(v, n));
    }
  }
}
