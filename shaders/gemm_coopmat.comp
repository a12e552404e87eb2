#version 450
// GEMM on cooperative matrices (VK_KHR_cooperative_matrix): fp16 inputs, fp32 accumulation.
// Host side: engine/ops/linear.cpp (linear layers whose weights are fp16, q8 or q4; the plan in
// engine/kernel_plan.cpp picks this where the device reports an fp16 x fp16 + fp32 size).
// W_QUANT: w is a block-quantized matrix (q8 / q4 by W_BITS, shaders/quant.glsl), its rows read
// as 32-bit words and dequantized into the fp16 slice as it is staged (TEXEL_K 4: K is whole
// blocks of 32), never expanded in device memory; a dequantized value beyond fp16's range
// saturates like an fp32 one, one below its smallest subnormal becomes 0.
//   y[b][m][n] = act(sum_k x[b][m][k] * w[b][n][k] + bias[n])
// A workgroup of SG_M x SG_N subgroups computes (CM_M*WM*SG_M) x (CM_N*WN*SG_N) outputs; each
// subgroup owns WM x WN accumulators of the device's CM_M x CM_N x CM_K multiply-add. Per step
// of CM_K*KSTEPS, the x and w slices are copied into shared memory as fp16 (the fetch
// converts fp32 activations; values beyond fp16's range saturate at +-65504), then the
// subgroups load their A and B fragments from there (B = w^T: w's rows read column-major).
// The accumulators leave through a small per-subgroup staging area, where bias, activation,
// the output type and the edges are handled per element.
//
// Written against GL_NV_cooperative_matrix, which Debian 12's glslang compiles, and rewritten
// into SPV_KHR_cooperative_matrix at build time (cmake/coopmat_nv_to_khr.py: the use of each
// matrix type is read off its shape, so A is CM_M x CM_K, B CM_K x CM_N, C CM_M x CM_N).
//! variant gemm_coopmat_f32 OUT_F16=0 W_QUANT=0
//! variant gemm_coopmat_f16out OUT_F16=1 W_QUANT=0
//! variant gemm_coopmat_q_f32 OUT_F16=0 W_QUANT=1
//! variant gemm_coopmat_q_f16out OUT_F16=1 W_QUANT=1
//! spirv coopmat-khr
#extension GL_GOOGLE_include_directive : require
#extension GL_NV_cooperative_matrix : require
#extension GL_KHR_memory_scope_semantics : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_EXT_shader_explicit_arithmetic_types_float16 : require
#include "common.glsl"
#include "quant.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const uint SG_M = 2;     // subgroups along rows
layout(constant_id = 4) const uint SG_N = 2;     // subgroups along columns
layout(constant_id = 5) const uint WM = 2;       // multiply-adds per subgroup along rows
layout(constant_id = 6) const uint WN = 2;       // ... along columns
layout(constant_id = 7) const uint KSTEPS = 2;   // CM_K blocks per shared-memory step
layout(constant_id = 8) const int TEXEL_K = 4;   // k values per texel of x and w: 4 or 1
layout(constant_id = 9) const int ACT = ACT_NONE;
layout(constant_id = 10) const bool HAS_BIAS = false;
layout(constant_id = 11) const int W_BITS = 8;   // W_QUANT: 8 (q8) or 4 (q4)
layout(constant_id = 15) const bool ACCUMULATE = false;  // y += the result (a fused residual add)
// (16: gemm_epilogue.glsl's SCALED.) The next k step's texels fetched into registers while this
// one is multiplied (as gemm_tiled.comp): global latency overlaps the multiply-adds.
layout(constant_id = 17) const bool PREFETCH = true;
// The device's multiply-add shape (ids fixed: the SPIR-V rewrite recognises them).
layout(constant_id = 20) const uint CM_M = 16;
layout(constant_id = 21) const uint CM_N = 16;
layout(constant_id = 22) const uint CM_K = 16;

TEXEL_INPUT(0, X, TEXEL_K)
#if W_QUANT
QUANT_INPUT(1, W)
#else
TEXEL_INPUT(1, W, TEXEL_K)
#endif
#include "gemm_epilogue.glsl"  // the bias binding (2), SCALED
layout(binding = 3) buffer Y { OUT_T y[]; };  // read back only with ACCUMULATE

layout(push_constant) uniform Push {
  int M, N, K;       // K in texels
  int ldx, ldw;      // row strides of x and w in texels (w quantized: in 32-bit words)
  int ldy;           // row stride of y in elements
  int xBatch, wBatch, yBatch;  // batch strides (texels, texels, elements); wBatch 0 shares w
} p;

const uint BM = CM_M * WM * SG_M, BN = CM_N * WN * SG_N, BK = CM_K * KSTEPS;
// Rows of the staged slices, padded by 8 halves (16 bytes) against bank conflicts.
const uint LD = BK + 8;
shared float16_t tileX[BM * LD];
shared float16_t tileW[BN * LD];
shared float staging[SG_M * SG_N * CM_M * CM_N];

// Invocation t fetches texels t, t + WG, ... of each slice (consecutive invocations along a
// row) into xNext / wNext; storeSlices writes them as fp16 into the shared slices.
const int WG = int(gl_WorkGroupSize.x);
const int X_FETCHES = (int(BM) * (int(BK) / TEXEL_K) + WG - 1) / WG;
const int W_FETCHES = (int(BN) * (int(BK) / TEXEL_K) + WG - 1) / WG;
vec4 xNext[X_FETCHES], wNext[W_FETCHES];

void fetchSlices(int img, int m0, int n0, int k0) {
  const int texelsPerRow = int(BK) / TEXEL_K, kt0 = k0 / TEXEL_K, t = int(gl_LocalInvocationIndex);
  [[unroll]] for (int f = 0; f < X_FETCHES; ++f) {
    const int i = t + f * WG, r = i / texelsPerRow, kt = i - r * texelsPerRow;
    const int row = m0 + r;
    xNext[f] = i < int(BM) * texelsPerRow && row < p.M && kt0 + kt < p.K
                   ? fetch_X(img * p.xBatch + row * p.ldx + kt0 + kt) : vec4(0.0);
  }
  [[unroll]] for (int f = 0; f < W_FETCHES; ++f) {
    const int i = t + f * WG, r = i / texelsPerRow, kt = i - r * texelsPerRow;
    const int row = n0 + r;
    vec4 v = vec4(0.0);
#if W_QUANT
    if (i < int(BN) * texelsPerRow && row < p.N && kt0 + kt < p.K) v = fetchq_W(img * p.wBatch + row * p.ldw, kt0 + kt, p.K);
#else
    if (i < int(BN) * texelsPerRow && row < p.N && kt0 + kt < p.K) v = fetch_W(img * p.wBatch + row * p.ldw + kt0 + kt);
#endif
    wNext[f] = v;
  }
}

// Values beyond fp16's range saturate at +-65504.
void storeSlices() {
  const int texelsPerRow = int(BK) / TEXEL_K, t = int(gl_LocalInvocationIndex);
  [[unroll]] for (int f = 0; f < X_FETCHES; ++f) {
    const int i = t + f * WG, r = i / texelsPerRow, kt = i - r * texelsPerRow;
    if (i < int(BM) * texelsPerRow) {
      const vec4 v = clamp(xNext[f], vec4(-65504.0), vec4(65504.0));
      [[unroll]] for (int c = 0; c < TEXEL_K; ++c) tileX[uint(r) * LD + uint(kt * TEXEL_K + c)] = float16_t(v[c]);
    }
  }
  [[unroll]] for (int f = 0; f < W_FETCHES; ++f) {
    const int i = t + f * WG, r = i / texelsPerRow, kt = i - r * texelsPerRow;
    if (i < int(BN) * texelsPerRow) {
      const vec4 v = clamp(wNext[f], vec4(-65504.0), vec4(65504.0));
      [[unroll]] for (int c = 0; c < TEXEL_K; ++c) tileW[uint(r) * LD + uint(kt * TEXEL_K + c)] = float16_t(v[c]);
    }
  }
}

void main() {
  const int img = int(gl_WorkGroupID.z);
  const int m0 = int(gl_WorkGroupID.x * BM), n0 = int(gl_WorkGroupID.y * BN);
  const uint sg = gl_SubgroupID;
  const uint sgRow = sg / SG_N, sgCol = sg % SG_N;

  fcoopmatNV<32, gl_ScopeSubgroup, CM_M, CM_N> acc[WM * WN];
  [[unroll]] for (uint i = 0; i < WM * WN; ++i) acc[i] = fcoopmatNV<32, gl_ScopeSubgroup, CM_M, CM_N>(0.0);

  const int K = p.K * TEXEL_K;
  fetchSlices(img, m0, n0, 0);
  for (int k0 = 0; k0 < K; k0 += int(BK)) {
    storeSlices();
    barrier();
    const bool more = k0 + int(BK) < K;
    if (PREFETCH && more) fetchSlices(img, m0, n0, k0 + int(BK));
    [[unroll]] for (uint ks = 0; ks < KSTEPS; ++ks) {
      fcoopmatNV<16, gl_ScopeSubgroup, CM_M, CM_K> a[WM];
      fcoopmatNV<16, gl_ScopeSubgroup, CM_K, CM_N> b[WN];
      [[unroll]] for (uint i = 0; i < WM; ++i)
        coopMatLoadNV(a[i], tileX, ((sgRow * WM + i) * CM_M) * LD + ks * CM_K, LD, false);
      [[unroll]] for (uint j = 0; j < WN; ++j)
        coopMatLoadNV(b[j], tileW, ((sgCol * WN + j) * CM_N) * LD + ks * CM_K, LD, true);
      [[unroll]] for (uint i = 0; i < WM; ++i)
        [[unroll]] for (uint j = 0; j < WN; ++j) acc[i * WN + j] = coopMatMulAddNV(a[i], b[j], acc[i * WN + j]);
    }
    barrier();
    if (!PREFETCH && more) fetchSlices(img, m0, n0, k0 + int(BK));
  }

  // Epilogue: each accumulator through this subgroup's staging area, one element per lane. The
  // area is the subgroup's own, so its lanes wait for one another only (a subgroup barrier with
  // a shared-memory barrier), not for the whole workgroup.
  const uint stage = sg * CM_M * CM_N;
  [[unroll]] for (uint i = 0; i < WM; ++i)
    [[unroll]] for (uint j = 0; j < WN; ++j) {
      coopMatStoreNV(acc[i * WN + j], staging, stage, CM_N, false);
      subgroupMemoryBarrierShared();
      subgroupBarrier();
      for (uint e = gl_SubgroupInvocationID; e < CM_M * CM_N; e += gl_SubgroupSize) {
        const int m = m0 + int((sgRow * WM + i) * CM_M + e / CM_N);
        const int n = n0 + int((sgCol * WN + j) * CM_N + e % CM_N);
        if (m >= p.M || n >= p.N) continue;
        float v = staging[stage + e];
        STORE_OUT(img * p.yBatch + m * p.ldy + n, gemm_epilogue(v, n));
      }
      subgroupMemoryBarrierShared();
      subgroupBarrier();
    }
}
