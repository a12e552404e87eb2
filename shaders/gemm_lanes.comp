#version 450
// Linear layer as GEMM whose subgroup's lanes split k: y[b][m][n] = act(sum_k x[b][m][k] *
// w[b][n][k] + bias[n]), fp32 x and w. Host side: engine/ops/linear.cpp (gemmLaunch, where
// KernelPlan::gemmLanesSplitK says so; gemmLanesRowBias for the convolutions' im2col products,
// whose bias is per row m: BIAS_PER_ROW, and for conv_transpose2d's, whose rows and columns
// scatter into its k x k output blocks: SCATTER_K).
//
// For JIT drivers that load a vector only when the lanes' addresses are consecutive words, and
// otherwise one lane at a time behind a branch (SwiftShader: its loads check at run time
// whether the lanes' offsets are equal or consecutive). gemm.comp's lanes each own rows of m,
// so their x loads are K words apart and every one is such a per-lane gather. Here the
// workgroup's x is one subgroup whose lane l reads words k + l of the same rows of x and w:
// every load is one vector load. Each lane sums its share of k for an RM x RN block, and
// subgroupAdd combines the lanes' sums once at the end. The workgroup's y subgroups take
// consecutive blocks of columns.
//
// Measured on SwiftShader 5.0.0 (Subzero, 2 cores), 1024^3 (spar-bench, docs/portability.md):
// 4.7 GFLOPS at 4 x 8 and 2 subgroups, against 0.6-0.8 for gemm.comp's blocks; the
// specialization constants must be written into the module for it (engine/spirv_freeze.h:
// 0.5 GFLOPS without), which the host does.
//! variant gemm_lanes_f32 OUT_F16=0
#extension GL_GOOGLE_include_directive : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const int RM = 4;         // rows of y per subgroup
layout(constant_id = 4) const int RN = 8;         // columns of y per subgroup
layout(constant_id = 5) const int TEXEL_K = 4;    // k values per texel of the bindings (4 or 1)
layout(constant_id = 6) const int ACT = ACT_NONE;
layout(constant_id = 7) const bool HAS_BIAS = false;
layout(constant_id = 8) const int LANES = 4;      // the workgroup's x size, one full subgroup
layout(constant_id = 9) const bool BIAS_PER_ROW = false;  // bias[m] instead of bias[n]
// SCATTER_K = k > 0 (conv_transpose2d, kernel = stride = k): row m = (co, a, b) of the kernel and
// column n = (i, j) of an input plane scatterW wide go to y[co * ldy + (i k + a) * scatterW k +
// j k + b], with bias[co].
layout(constant_id = 10) const int SCATTER_K = 0;
layout(constant_id = 15) const bool ACCUMULATE = false;  // y += the result (a fused residual add)

TEXEL_INPUT(0, X, TEXEL_K)
TEXEL_INPUT(1, W, TEXEL_K)
#include "gemm_epilogue.glsl"  // the bias binding (2), SCALED
layout(binding = 3) buffer Y { OUT_T y[]; };  // read back only with ACCUMULATE

// Word i of x and w (fp32: the host binds no fp16 here).
#if defined(STORAGE_INPUTS) && STORAGE_INPUTS
#define X_AT(i) uintBitsToFloat(X_w[i])
#define W_AT(i) uintBitsToFloat(W_w[i])
#else
#define X_AT(i) fetch_X((i) / TEXEL_K)[(i) % TEXEL_K]
#define W_AT(i) fetch_W((i) / TEXEL_K)[(i) % TEXEL_K]
#endif

layout(push_constant) uniform Push {
  int M, N, K;       // K in texels
  int ldx, ldw;      // row strides of x and w in texels
  int ldy;           // row stride of y in elements
  int xBatch, wBatch, yBatch;  // batch strides (texels, texels, elements); wBatch 0 shares w
  int yBase;         // y[0][0] in y's binding
  int scatterW;      // SCATTER_K: the input plane's width
} p;

void main() {
  const int lane = int(gl_SubgroupInvocationID);
  const int m0 = int(gl_WorkGroupID.x) * RM;
  const int n0 = int(gl_WorkGroupID.y * gl_WorkGroupSize.y + gl_LocalInvocationID.y) * RN;
  const int b = int(gl_GlobalInvocationID.z);
  const int K = p.K * TEXEL_K;  // in words
  // Rows and columns past the edge re-read the last one; their results are not stored.
  int xRow[RM], wRow[RN];
  [[unroll]] for (int r = 0; r < RM; ++r) xRow[r] = (b * p.xBatch + min(m0 + r, p.M - 1) * p.ldx) * TEXEL_K + lane;
  [[unroll]] for (int c = 0; c < RN; ++c) wRow[c] = (b * p.wBatch + min(n0 + c, p.N - 1) * p.ldw) * TEXEL_K + lane;

  float acc[RM * RN];
  [[unroll]] for (int i = 0; i < RM * RN; ++i) acc[i] = 0.0;
#define GEMM_LANES_STEP(k, inside)                                                          \
  {                                                                                         \
    float a[RM], w[RN];                                                                     \
    [[unroll]] for (int r = 0; r < RM; ++r) {                                               \
      const float v = X_AT(xRow[r] + (k));                                                  \
      a[r] = (inside) ? v : 0.0;                                                            \
    }                                                                                       \
    [[unroll]] for (int c = 0; c < RN; ++c) {                                               \
      const float v = W_AT(wRow[c] + (k));                                                  \
      w[c] = (inside) ? v : 0.0;                                                            \
    }                                                                                       \
    [[unroll]] for (int c = 0; c < RN; ++c)                                                 \
      [[unroll]] for (int r = 0; r < RM; ++r) acc[r * RN + c] = fma(a[r], w[c], acc[r * RN + c]); \
  }
  // Every lane runs the same trips (no lane masked off, so every load stays a vector load);
  // in the last, partial one the lanes past K read their row's first word and use zeros.
  const int whole = K - K % LANES;
  int k = 0;
  for (; k < whole; k += LANES) GEMM_LANES_STEP(k, true)
  if (k < K) {
    const bool inside = k + lane < K;
    GEMM_LANES_STEP(inside ? k : -lane, inside)
  }
  [[unroll]] for (int i = 0; i < RM * RN; ++i) acc[i] = subgroupAdd(acc[i]);

  // Lane l stores the columns c with c % LANES == l.
  [[unroll]] for (int r = 0; r < RM; ++r) {
    const int m = m0 + r;
    [[unroll]] for (int c = 0; c < RN; ++c) {
      const int n = n0 + c;
      if (c % LANES != lane || m >= p.M || n >= p.N) continue;
      int at = m * p.ldy + n, bi = BIAS_PER_ROW ? m : n;
      if (SCATTER_K > 0) {
        const int co = m / (SCATTER_K * SCATTER_K), a = (m / SCATTER_K) % SCATTER_K, e = m % SCATTER_K;
        const int i = n / p.scatterW, j = n - i * p.scatterW;
        at = co * p.ldy + (i * SCATTER_K + a) * p.scatterW * SCATTER_K + j * SCATTER_K + e;
        bi = co;
      }
      float v = acc[r * RN + c];
      STORE_OUT(p.yBase + b * p.yBatch + at, gemm_epilogue(v, bi));
    }
  }
}
