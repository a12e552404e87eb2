#version 450
// Fused multi-head attention on cooperative matrices (VK_KHR_cooperative_matrix): q, k, v
// rounded to fp16, scores and output accumulated in fp32, softmax in fp32. Host side:
// engine/ops/attention.cpp (used for fp16 inputs or fp16 layers where the device has
// cooperative matrices; attention_tiled.comp otherwise). Bindings and push constants are
// attention.comp's.
//
// A workgroup of NSG subgroups takes NSG * CM_M consecutive queries of one head; each subgroup
// owns CM_M of them, their q as DH / CM_K fragments kept in registers. Per block of BKV keys:
//   1. the workgroup stages the block's k and v rows in shared memory as fp16;
//   2. each subgroup multiplies its q by k^T (k rows read column-major) into fp32 scores;
//   3. one invocation per query row folds the scores into the row's running max and sum (the
//      online softmax of attention.comp: max from -FLT_MAX/2, masked keys exactly 0), writes
//      the probabilities as fp16 and rescales the row's output by exp(old max - new max);
//   4. each subgroup adds probabilities times v to its output, loaded from and stored back to
//      shared memory as fp32 accumulators.
// The output rows are divided by their sums (guarded) at the end.
// QK_NORM / QK_ROPE (shaders/attention_prep.glsl, the *_prep variants): q and k rows are staged
// one row an invocation instead, each normed and rotated in fp32 before its rounding to fp16.
// Written against GL_NV_cooperative_matrix and rewritten into SPV_KHR_cooperative_matrix at
// build time (cmake/coopmat_nv_to_khr.py): A is CM_M x CM_K, B CM_K x CM_N, C CM_M x CM_N.
//! variant attention_coopmat_f32 OUT_F16=0
//! variant attention_coopmat_f16out OUT_F16=1
//! variant attention_coopmat_prep_f32 OUT_F16=0 QK_PREP_BINDINGS=1
//! variant attention_coopmat_prep_f16out OUT_F16=1 QK_PREP_BINDINGS=1
//! spirv coopmat-khr
#extension GL_GOOGLE_include_directive : require
#extension GL_NV_cooperative_matrix : require
#extension GL_KHR_memory_scope_semantics : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_EXT_shader_explicit_arithmetic_types_float16 : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const uint DH = 64;       // head dimension (multiple of CM_K and CM_N)
layout(constant_id = 4) const uint NSG = 4;       // subgroups per workgroup
layout(constant_id = 5) const uint BKV = 32;      // keys per block (multiple of CM_N and CM_K)
layout(constant_id = 6) const bool CAUSAL = false;
layout(constant_id = 20) const uint CM_M = 16;
layout(constant_id = 21) const uint CM_N = 16;
layout(constant_id = 22) const uint CM_K = 16;

TEXEL_INPUT(0, Q, 4)
TEXEL_INPUT(1, K, 4)
TEXEL_INPUT(2, V, 4)
layout(binding = 3) writeonly buffer O { OUT_T o[]; };

layout(push_constant) uniform Push {
  int Nq, Nk;
  int qStride, kStride, vStride, oStride;  // row strides in elements (q, k, v: multiples of 4)
  int qOff, kOff, vOff, oOff;              // column of head 0 in elements
  int qBatch, kBatch, vBatch, oBatch;      // batch strides in elements
  float scaleLog2;                         // softmax scale times log2(e)
  float qkEps;                             // QK_NORM's epsilon
  int ropePrefix;                          // QK_ROPE: leading tokens left unrotated
} p;
#include "attention_prep.glsl"

const float kNegLarge = -3.4028235e38 / 2.0;
const uint BQ = NSG * CM_M;
const uint LD = DH + 8;               // fp16 rows of staged q / k / v, padded by 16 bytes
const uint ROWS = BQ > BKV ? BQ : BKV;
const uint LP = BKV + 8;              // fp16 rows of probabilities
shared float16_t stagedK[ROWS * LD];  // q at the start, then each block's k
shared float16_t stagedV[BKV * LD];
shared float scores[NSG * CM_M * BKV];
shared float16_t probs[NSG * CM_M * LP];
shared float outAcc[NSG * CM_M * DH];
shared float rowMax[BQ], rowSum[BQ];

// Rows [row0, row0 + rows) of a head (q, k or v) into dst as fp16, zero past the last row.
void stage(bool isV, bool isQ, int b, int head, int row0, uint rows) {
  const uint d4 = DH / 4;
  for (uint i = gl_LocalInvocationIndex; i < rows * d4; i += gl_WorkGroupSize.x) {
    const uint r = i / d4, c = i % d4;
    const int row = row0 + int(r);
    vec4 x = vec4(0.0);
    if (isQ) {
      if (row < p.Nq) x = fetch_Q((b * p.qBatch + row * p.qStride + p.qOff + head * int(DH)) / 4 + int(c));
    } else if (isV) {
      if (row < p.Nk) x = fetch_V((b * p.vBatch + row * p.vStride + p.vOff + head * int(DH)) / 4 + int(c));
    } else {
      if (row < p.Nk) x = fetch_K((b * p.kBatch + row * p.kStride + p.kOff + head * int(DH)) / 4 + int(c));
    }
    const f16vec4 h = f16vec4(clamp(x, vec4(-65504.0), vec4(65504.0)));
    [[unroll]] for (uint e = 0; e < 4; ++e) {
      if (isV) stagedV[r * LD + c * 4 + e] = h[e];
      else stagedK[r * LD + c * 4 + e] = h[e];
    }
  }
}

// QK_PREP: rows [row0, row0 + rows) of the q (isQ) or k heads into stagedK as fp16, one row an
// invocation, each prepared in fp32 first; zero past the last row.
void stagePrepared(bool isQ, int b, int head, int row0, uint rows) {
  const int n = isQ ? p.Nq : p.Nk;
  for (uint r = gl_LocalInvocationIndex; r < rows; r += gl_WorkGroupSize.x) {
    const int row = row0 + int(r);
    vec4 h[DH / 4];
    const int base = isQ ? (b * p.qBatch + row * p.qStride + p.qOff + head * int(DH)) / 4
                         : (b * p.kBatch + row * p.kStride + p.kOff + head * int(DH)) / 4;
    [[unroll]] for (int u = 0; u < QK_DH / 4; ++u) h[u] = row < n ? (isQ ? fetch_Q(base + u) : fetch_K(base + u)) : vec4(0.0);
    if (row < n) QK_PREP_HEAD(h, isQ ? 0 : 1, row)
    [[unroll]] for (int u = 0; u < QK_DH / 4; ++u) {
      const f16vec4 x = f16vec4(clamp(h[u], vec4(-65504.0), vec4(65504.0)));
      [[unroll]] for (uint e = 0; e < 4; ++e) stagedK[r * LD + uint(u) * 4 + e] = x[e];
    }
  }
}

void main() {
  const int q0 = int(gl_WorkGroupID.x * BQ);
  const int head = int(gl_WorkGroupID.y);
  const int b = int(gl_WorkGroupID.z);
  const uint sg = gl_SubgroupID, lane = gl_SubgroupInvocationID;
  const uint r0 = sg * CM_M;  // this subgroup's first row of the workgroup's queries

  // q fragments, staged through the k area once.
  if (QK_PREP) stagePrepared(true, b, head, q0, BQ);
  else stage(false, true, b, head, q0, BQ);
  for (uint i = gl_LocalInvocationIndex; i < BQ; i += gl_WorkGroupSize.x) {
    rowMax[i] = kNegLarge;
    rowSum[i] = 0.0;
  }
  for (uint i = gl_LocalInvocationIndex; i < NSG * CM_M * DH; i += gl_WorkGroupSize.x) outAcc[i] = 0.0;
  barrier();
  fcoopmatNV<16, gl_ScopeSubgroup, CM_M, CM_K> qa[DH / CM_K];
  [[unroll]] for (uint c = 0; c < DH / CM_K; ++c) coopMatLoadNV(qa[c], stagedK, r0 * LD + c * CM_K, LD, false);
  barrier();

  const int kEnd = CAUSAL ? min(p.Nk, q0 + int(BQ)) : p.Nk;
  for (int kb = 0; kb < kEnd; kb += int(BKV)) {
    if (QK_PREP) stagePrepared(false, b, head, kb, BKV);
    else stage(false, false, b, head, kb, BKV);
    stage(true, false, b, head, kb, BKV);
    barrier();
    // scores = q k^T for this subgroup's rows
    [[unroll]] for (uint j = 0; j < BKV / CM_N; ++j) {
      fcoopmatNV<32, gl_ScopeSubgroup, CM_M, CM_N> s = fcoopmatNV<32, gl_ScopeSubgroup, CM_M, CM_N>(0.0);
      [[unroll]] for (uint c = 0; c < DH / CM_K; ++c) {
        fcoopmatNV<16, gl_ScopeSubgroup, CM_K, CM_N> kt;
        coopMatLoadNV(kt, stagedK, (j * CM_N) * LD + c * CM_K, LD, true);
        s = coopMatMulAddNV(qa[c], kt, s);
      }
      coopMatStoreNV(s, scores, r0 * BKV + j * CM_N, BKV, false);
    }
    barrier();
    // online softmax, one invocation per query row of the subgroup
    for (uint r = lane; r < CM_M; r += gl_SubgroupSize) {
      const uint row = r0 + r;
      const int q = q0 + int(row);
      float m = rowMax[row];
      [[unroll]] for (uint j = 0; j < BKV; ++j) {
        const int key = kb + int(j);
        const bool valid = key < p.Nk && (!CAUSAL || key <= q);
        m = max(m, valid ? scores[row * BKV + j] * p.scaleLog2 : kNegLarge);
      }
      const float correction = exp2(rowMax[row] - m);
      float sum = rowSum[row] * correction;
      [[unroll]] for (uint j = 0; j < BKV; ++j) {
        const int key = kb + int(j);
        const bool valid = key < p.Nk && (!CAUSAL || key <= q);
        const float16_t e = float16_t(valid ? exp2(scores[row * BKV + j] * p.scaleLog2 - m) : 0.0);
        probs[row * LP + j] = e;
        sum += float(e);
      }
      rowMax[row] = m;
      rowSum[row] = sum;
      for (uint d = 0; d < DH; ++d) outAcc[row * DH + d] *= correction;
    }
    barrier();
    // output += probabilities v
    [[unroll]] for (uint n = 0; n < DH / CM_N; ++n) {
      fcoopmatNV<32, gl_ScopeSubgroup, CM_M, CM_N> acc;
      coopMatLoadNV(acc, outAcc, r0 * DH + n * CM_N, DH, false);
      [[unroll]] for (uint kc = 0; kc < BKV / CM_K; ++kc) {
        fcoopmatNV<16, gl_ScopeSubgroup, CM_M, CM_K> pa;
        fcoopmatNV<16, gl_ScopeSubgroup, CM_K, CM_N> vb;
        coopMatLoadNV(pa, probs, r0 * LP + kc * CM_K, LP, false);
        coopMatLoadNV(vb, stagedV, (kc * CM_K) * LD + n * CM_N, LD, false);
        acc = coopMatMulAddNV(pa, vb, acc);
      }
      coopMatStoreNV(acc, outAcc, r0 * DH + n * CM_N, DH, false);
    }
    barrier();
  }

  for (uint i = gl_LocalInvocationIndex; i < BQ * DH; i += gl_WorkGroupSize.x) {
    const uint row = i / DH, d = i % DH;
    const int q = q0 + int(row);
    if (q >= p.Nq) continue;
    const float inv = rowSum[row] > 0.0 ? 1.0 / rowSum[row] : 0.0;
    o[b * p.oBatch + q * p.oStride + p.oOff + head * int(DH) + int(d)] = TO_OUT(outAcc[row * DH + d] * inv);
  }
}
