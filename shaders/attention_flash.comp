#version 450
// Fused multi-head attention for GPUs with tiles of scores: several invocations share each
// query, o = softmax(q k^T * scale (+ causal mask)) v per head. Host side:
// engine/ops/attention.cpp (KernelPlan::attentionLanes > 0); attention_tiled.comp (one query an
// invocation) stays the other candidate the GPU tuner times (engine/kernel_tuner.cpp).
//
// A workgroup takes BQ consecutive queries of one head; its invocations form groups of LANES,
// each group owning 4 queries. Per block of BKEYS keys:
//   1. S = q k^T: lane j of a group scores its 4 queries against keys j, j + LANES, ...
//      (a 4 x BKEYS/LANES register tile, q and k rows read as vec4s from shared memory);
//   2. online softmax: the row max and the row sum are combined over the group's lanes
//      (subgroup shuffles with SG_ROWS, else through shared memory), every lane keeps the same
//      running max and sum, and writes its probabilities into shared memory;
//   3. O += P v: lane j accumulates texels j, j + LANES, ... of its 4 queries' outputs.
// While 2 and 3 run, the next block's k and v texels are already fetched into registers
// (ncnn's prefetch), so global latency overlaps arithmetic. Numerics are attention.comp's:
// running max from -FLT_MAX/2 (never -inf), masked keys contribute exactly 0, guarded final
// division. Bindings and push constants are attention.comp's; with QK_NORM / QK_ROPE
// (shaders/attention_prep.glsl) the q rows are prepared once in shared memory and each block's
// k rows after they arrive.
//! variant attention_flash_f32 OUT_F16=0 SG_ROWS=0
//! variant attention_flash_f16out OUT_F16=1 SG_ROWS=0
//! variant attention_flash_prep_f32 OUT_F16=0 SG_ROWS=0 QK_PREP_BINDINGS=1
//! variant attention_flash_prep_f16out OUT_F16=1 SG_ROWS=0 QK_PREP_BINDINGS=1
//! variant attention_flash_sg_f32 OUT_F16=0 SG_ROWS=1
//! variant attention_flash_sg_f16out OUT_F16=1 SG_ROWS=1
//! variant attention_flash_sg_prep_f32 OUT_F16=0 SG_ROWS=1 QK_PREP_BINDINGS=1
//! variant attention_flash_sg_prep_f16out OUT_F16=1 SG_ROWS=1 QK_PREP_BINDINGS=1
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"
#if SG_ROWS
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_shuffle : require
#endif

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;  // BQ / 4 * LANES x 1 x 1
layout(constant_id = 3) const int DH = 64;      // head dimension (multiple of 4)
layout(constant_id = 4) const int BKEYS = 32;   // keys a block (a multiple of LANES)
layout(constant_id = 5) const bool CAUSAL = false;
layout(constant_id = 6) const int BQ = 32;      // queries a workgroup (a multiple of 4)
layout(constant_id = 7) const int LANES = 16;   // invocations sharing 4 queries (SG_ROWS: a power of two)

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
const int D4 = DH / 4;
const int ROW = D4 + 1;                        // shared row pitch in texels: lanes reading
                                               // different rows at one texel hit different banks
const int WG = BQ / 4 * LANES;
const int KPL = BKEYS / LANES;                 // keys a lane scores
const int DPL = (D4 + LANES - 1) / LANES;      // output texels a lane accumulates
const int FETCHES = (BKEYS * D4 + WG - 1) / WG;  // k (and v) texels an invocation fetches a block
shared vec4 blockQ[BQ * ROW];
shared vec4 blockK[BKEYS * ROW];
shared vec4 blockV[BKEYS * ROW];
shared float blockP[BQ * (BKEYS + 1)];
#if !SG_ROWS
shared float partial[BQ * LANES];
#endif

int group, lane;  // this invocation's group (4 queries) and its lane in it

// The max (or sum) over a group's lanes of each of its 4 rows; every lane gets the same values.
vec4 groupReduce(vec4 v, bool isMax) {
#if SG_ROWS
  // The group is LANES consecutive invocations of one subgroup (see main): xor butterflies.
  for (int m = 1; m < LANES; m *= 2) {
    const vec4 o = subgroupShuffleXor(v, uint(m));
    v = isMax ? max(v, o) : v + o;
  }
  return v;
#else
  [[unroll]] for (int i = 0; i < 4; ++i) partial[(group * 4 + i) * LANES + lane] = v[i];
  barrier();
  vec4 r = vec4(isMax ? kNegLarge : 0.0);
  for (int l = 0; l < LANES; ++l)  // the same order in every lane: the same result
    [[unroll]] for (int i = 0; i < 4; ++i) {
      const float x = partial[(group * 4 + i) * LANES + l];
      r[i] = isMax ? max(r[i], x) : r[i] + x;
    }
  barrier();
  return r;
#endif
}

void main() {
  const int t = int(gl_LocalInvocationIndex);
#if SG_ROWS
  // Groups from the subgroups' own numbering, so a group's lanes are one cluster of a subgroup
  // whatever order the device gives invocations to subgroups (full subgroups of a multiple of
  // LANES: engine/ops/attention.cpp).
  const int index = int(gl_SubgroupID * gl_SubgroupSize + gl_SubgroupInvocationID);
#else
  const int index = t;
#endif
  group = index / LANES;
  lane = index % LANES;
  const int q0 = int(gl_WorkGroupID.x) * BQ;
  const int head = int(gl_WorkGroupID.y);
  const int b = int(gl_WorkGroupID.z);

  // The workgroup's q rows (rows past Nq repeat the last one; their outputs are not written).
  const int qBase = (b * p.qBatch + p.qOff + head * DH) / 4, qRow = p.qStride / 4;
  for (int i = t; i < BQ * D4; i += WG) {
    const int r = i / D4, d = i % D4;
    blockQ[r * ROW + d] = fetch_Q(qBase + min(q0 + r, p.Nq - 1) * qRow + d);
  }
  barrier();
  if (QK_PREP) {  // each q row normed and rotated once, by one invocation
    for (int r = t; r < BQ; r += WG) {
      vec4 row[D4];
      [[unroll]] for (int d = 0; d < D4; ++d) row[d] = blockQ[r * ROW + d];
      QK_PREP_HEAD(row, 0, min(q0 + r, p.Nq - 1))
      [[unroll]] for (int d = 0; d < D4; ++d) blockQ[r * ROW + d] = row[d];
    }
  }

  const int kBase = (b * p.kBatch + p.kOff + head * DH) / 4, kRow = p.kStride / 4;
  const int vBase = (b * p.vBatch + p.vOff + head * DH) / 4, vRow = p.vStride / 4;
  // With a causal mask no query of this workgroup sees keys past its last query.
  const int kEnd = CAUSAL ? min(p.Nk, q0 + BQ) : p.Nk;

  vec4 nextK[FETCHES], nextV[FETCHES];
  [[unroll]] for (int f = 0; f < FETCHES; ++f) {  // block 0
    const int i = t + f * WG, key = i / D4, d = i % D4;
    const bool inside = i < BKEYS * D4 && key < kEnd;
    nextK[f] = inside ? fetch_K(kBase + key * kRow + d) : vec4(0.0);
    nextV[f] = inside ? fetch_V(vBase + key * vRow + d) : vec4(0.0);
  }

  vec4 acc[4 * DPL];
  [[unroll]] for (int i = 0; i < 4 * DPL; ++i) acc[i] = vec4(0.0);
  vec4 runMax = vec4(kNegLarge), runSum = vec4(0.0);
  const ivec4 rowQ = q0 + group * 4 + ivec4(0, 1, 2, 3);

  for (int kb = 0; kb < kEnd; kb += BKEYS) {
    [[unroll]] for (int f = 0; f < FETCHES; ++f) {
      const int i = t + f * WG;
      if (i < BKEYS * D4) {
        const int key = i / D4, d = i % D4;
        blockK[key * ROW + d] = nextK[f];
        blockV[key * ROW + d] = nextV[f];
      }
    }
    barrier();
    if (QK_PREP) {
      for (int r = t; r < BKEYS && kb + r < kEnd; r += WG) {
        vec4 row[D4];
        [[unroll]] for (int d = 0; d < D4; ++d) row[d] = blockK[r * ROW + d];
        QK_PREP_HEAD(row, 1, kb + r)
        [[unroll]] for (int d = 0; d < D4; ++d) blockK[r * ROW + d] = row[d];
      }
      barrier();
    }
    // The next block's texels on their way while this one is computed.
    const int next = kb + BKEYS;
    [[unroll]] for (int f = 0; f < FETCHES; ++f) {
      const int i = t + f * WG, key = next + i / D4, d = i % D4;
      const bool inside = i < BKEYS * D4 && key < kEnd;
      nextK[f] = inside ? fetch_K(kBase + key * kRow + d) : vec4(0.0);
      nextV[f] = inside ? fetch_V(vBase + key * vRow + d) : vec4(0.0);
    }

    // 1. scores of the group's 4 queries against this lane's keys
    vec4 s[KPL];  // s[c][i]: key lane + c * LANES, query i
    [[unroll]] for (int c = 0; c < KPL; ++c) s[c] = vec4(0.0);
    for (int d = 0; d < D4; ++d) {
      vec4 qv[4];
      [[unroll]] for (int i = 0; i < 4; ++i) qv[i] = blockQ[(group * 4 + i) * ROW + d];
      [[unroll]] for (int c = 0; c < KPL; ++c) {
        const vec4 kv = blockK[(lane + c * LANES) * ROW + d];
        [[unroll]] for (int i = 0; i < 4; ++i) s[c][i] += dot(qv[i], kv);
      }
    }
    // 2. online softmax over the block
    vec4 localMax = vec4(kNegLarge);
    [[unroll]] for (int c = 0; c < KPL; ++c) {
      const int key = kb + lane + c * LANES;
      [[unroll]] for (int i = 0; i < 4; ++i) {
        const bool valid = key < p.Nk && (!CAUSAL || key <= rowQ[i]);
        s[c][i] = valid ? s[c][i] * p.scaleLog2 : kNegLarge;
      }
      localMax = max(localMax, s[c]);
    }
    const vec4 newMax = max(runMax, groupReduce(localMax, true));
    const vec4 correction = exp2(runMax - newMax);
    runMax = newMax;
    vec4 localSum = vec4(0.0);
    [[unroll]] for (int c = 0; c < KPL; ++c) {
      const int key = kb + lane + c * LANES;
      [[unroll]] for (int i = 0; i < 4; ++i) {
        const bool valid = key < p.Nk && (!CAUSAL || key <= rowQ[i]);
        const float pr = valid ? exp2(s[c][i] - newMax[i]) : 0.0;
        blockP[(group * 4 + i) * (BKEYS + 1) + lane + c * LANES] = pr;
        localSum[i] += pr;
      }
    }
    runSum = runSum * correction + groupReduce(localSum, false);
    [[unroll]] for (int i = 0; i < 4; ++i)
      [[unroll]] for (int c = 0; c < DPL; ++c) acc[i * DPL + c] *= correction[i];
    barrier();
    // 3. the group's outputs from this block's values
    const int keys = min(BKEYS, kEnd - kb);
    for (int j = 0; j < keys; ++j) {
      vec4 pr;
      [[unroll]] for (int i = 0; i < 4; ++i) pr[i] = blockP[(group * 4 + i) * (BKEYS + 1) + j];
      [[unroll]] for (int c = 0; c < DPL; ++c) {
        const int d = lane + c * LANES;
        if (d < D4) {
          const vec4 vv = blockV[j * ROW + d];
          [[unroll]] for (int i = 0; i < 4; ++i) acc[i * DPL + c] = fma(vec4(pr[i]), vv, acc[i * DPL + c]);
        }
      }
    }
    barrier();
  }

  [[unroll]] for (int i = 0; i < 4; ++i) {
    const int q = rowQ[i];
    if (q >= p.Nq) break;
    const float inv = runSum[i] > 0.0 ? 1.0 / runSum[i] : 0.0;
    const int base = b * p.oBatch + q * p.oStride + p.oOff + head * DH;
    [[unroll]] for (int c = 0; c < DPL; ++c) {
      const int d = lane + c * LANES;
      if (d < D4)
        [[unroll]] for (int e = 0; e < 4; ++e) o[base + d * 4 + e] = TO_OUT(acc[i * DPL + c][e] * inv);
    }
  }
}
