#version 450
// Fused multi-head attention whose subgroup's lanes split the head dimension:
// o = softmax(q k^T * scale (+ causal mask)) v per head, online softmax over blocks of KB keys.
// Host side: engine/ops/attention.cpp (where KernelPlan::attentionLanesSplitDim says so).
//
// The attention counterpart of gemm_lanes.comp, for JIT drivers whose loads are vector loads
// only where the lanes' addresses are consecutive words (SwiftShader): attention.comp's lanes
// each own queries, so their q loads are a row apart, and its keys are read through texels of 4.
// Here a subgroup of LANES lanes owns QPS queries of one head and lane l owns channels l,
// LANES + l, ... of them: every q, k and v load and every store of o is one word a lane at
// consecutive addresses. A block's scores are each lane's partial dot products over its
// channels, summed over the lanes by subgroupAdd; the softmax then runs on values that are the
// same in every lane, and each lane accumulates p v for its own channels (no reduction there).
// Numerics as attention.comp: running max from -FLT_MAX/2, masked keys exactly 0, the final
// division guarded. fp32 q, k and v only (the host binds no fp16 inputs here).
//
// QK_NORM / QK_ROPE (shaders/attention_prep.glsl, the *_prep variants): a head's sum of squares
// is the lanes' partial sums added by subgroupAdd; RoPE pairs channel c with c + DH / 2, which
// the same lane owns when DH / LANES is even (the host asks for RoPE here only then). The queries
// are prepared once; the keys' texels are weighted and rotated as they are loaded, and each score
// is multiplied by its key's 1 / rms.
//! variant attention_lanes_f32 OUT_F16=0
//! variant attention_lanes_f16out OUT_F16=1
//! variant attention_lanes_prep_f32 OUT_F16=0 QK_PREP_BINDINGS=1
//! variant attention_lanes_prep_f16out OUT_F16=1 QK_PREP_BINDINGS=1
#extension GL_GOOGLE_include_directive : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const int DH = 64;     // head dimension (a multiple of LANES and of 4)
layout(constant_id = 4) const int QPS = 2;     // queries per subgroup
layout(constant_id = 5) const int KB = 4;      // keys per block
layout(constant_id = 6) const bool CAUSAL = false;
layout(constant_id = 7) const int LANES = 4;   // the workgroup's x size, one full subgroup

TEXEL_INPUT(0, Q, 4)
TEXEL_INPUT(1, K, 4)
TEXEL_INPUT(2, V, 4)
layout(binding = 3) writeonly buffer O { OUT_T o[]; };

// Word i of q, k and v.
#if defined(STORAGE_INPUTS) && STORAGE_INPUTS
#define Q_AT(i) uintBitsToFloat(Q_w[i])
#define K_AT(i) uintBitsToFloat(K_w[i])
#define V_AT(i) uintBitsToFloat(V_w[i])
#else
#define Q_AT(i) fetch_Q((i) >> 2)[(i) & 3]
#define K_AT(i) fetch_K((i) >> 2)[(i) & 3]
#define V_AT(i) fetch_V((i) >> 2)[(i) & 3]
#endif

layout(push_constant) uniform Push {
  int Nq, Nk;
  int qStride, kStride, vStride, oStride;  // row strides in elements
  int qOff, kOff, vOff, oOff;              // column of head 0 in elements
  int qBatch, kBatch, vBatch, oBatch;      // batch strides in elements
  float scaleLog2;                         // softmax scale times log2(e)
  float qkEps;                             // QK_NORM's epsilon
  int ropePrefix;                          // QK_ROPE: leading tokens left unrotated
} p;
#include "attention_prep.glsl"

// Word i of the norm weights and the RoPE tables (the *_prep variants).
#if QK_PREP_BINDINGS && defined(STORAGE_INPUTS) && STORAGE_INPUTS
#define NORM_W_AT(i) uintBitsToFloat(QK_NORM_W_w[i])
#define SIN_AT(i) uintBitsToFloat(ROPE_SIN_w[i])
#define COS_AT(i) uintBitsToFloat(ROPE_COS_w[i])
#elif QK_PREP_BINDINGS
#define NORM_W_AT(i) fetch_QK_NORM_W((i) >> 2)[(i) & 3]
#define SIN_AT(i) fetch_ROPE_SIN((i) >> 2)[(i) & 3]
#define COS_AT(i) fetch_ROPE_COS((i) >> 2)[(i) & 3]
#else
#define NORM_W_AT(i) 1.0
#define SIN_AT(i) 0.0
#define COS_AT(i) 1.0
#endif

// k_norm's weight of channel c (1 without QK_NORM: the binding then holds a placeholder).
float lanes_k_weight(int c) { return QK_NORM ? NORM_W_AT(DH + c) : 1.0; }

// Rotates this lane's channels c = lane + t LANES and c + DH / 2 (its t + DL / 2) of a token's head.
void lanes_rotate(inout float a, inout float b, int token, int c) {
  if (!QK_ROPE || token < p.ropePrefix) return;
  const int row = (token - p.ropePrefix) * DH;
  const float na = a * COS_AT(row + c) - b * SIN_AT(row + c);
  const float nb = b * COS_AT(row + c + DH / 2) + a * SIN_AT(row + c + DH / 2);
  a = na;
  b = nb;
}

const float kNegLarge = -3.4028235e38 / 2.0;

void main() {
  const int lane = int(gl_SubgroupInvocationID);
  const int q0 = int(gl_WorkGroupID.x * gl_WorkGroupSize.y + gl_LocalInvocationID.y) * QPS;
  const int head = int(gl_WorkGroupID.y);
  const int b = int(gl_WorkGroupID.z);
  const int DL = DH / LANES;  // channels a lane owns

  // The subgroup's queries, this lane's channels, held for the whole key loop. Queries past
  // Nq read the last one (their results are not stored), so every lane runs every trip.
  float qv[QPS * DL];
  [[unroll]] for (int i = 0; i < QPS; ++i) {
    const int at = b * p.qBatch + min(q0 + i, p.Nq - 1) * p.qStride + p.qOff + head * DH + lane;
    [[unroll]] for (int t = 0; t < DL; ++t) qv[i * DL + t] = Q_AT(at + t * LANES);
    if (QK_NORM) {
      float ss = 0.0;
      [[unroll]] for (int t = 0; t < DL; ++t) ss += qv[i * DL + t] * qv[i * DL + t];
      const float r = qk_rstd(subgroupAdd(ss));
      [[unroll]] for (int t = 0; t < DL; ++t) qv[i * DL + t] = qv[i * DL + t] * r * NORM_W_AT(lane + t * LANES);
    }
    if (QK_ROPE)
      [[unroll]] for (int t = 0; t < DL / 2; ++t)
        lanes_rotate(qv[i * DL + t], qv[i * DL + t + DL / 2], min(q0 + i, p.Nq - 1), lane + t * LANES);
  }
  const int kBase = b * p.kBatch + p.kOff + head * DH + lane;
  const int vBase = b * p.vBatch + p.vOff + head * DH + lane;

  float runMax[QPS], runSum[QPS], acc[QPS * DL];
  [[unroll]] for (int i = 0; i < QPS; ++i) { runMax[i] = kNegLarge; runSum[i] = 0.0; }
  [[unroll]] for (int i = 0; i < QPS * DL; ++i) acc[i] = 0.0;

  // With a causal mask no query here sees keys past the subgroup's last query.
  const int kEnd = CAUSAL ? min(p.Nk, q0 + QPS) : p.Nk;
  for (int kb = 0; kb < kEnd; kb += KB) {
    int kAt[KB], vAt[KB];
    [[unroll]] for (int j = 0; j < KB; ++j) {
      const int key = min(kb + j, p.Nk - 1);
      kAt[j] = kBase + key * p.kStride;
      vAt[j] = vBase + key * p.vStride;
    }
    // Scores: this lane's share of every dot product, then the lanes' sum.
    float s[QPS * KB];
    [[unroll]] for (int i = 0; i < QPS * KB; ++i) s[i] = 0.0;
    if (QK_PREP) {
      // Channel t (and, with RoPE, its partner t + DL / 2) of each key: weighted, rotated, and
      // its square added to the key's partial sum.
      float kss[KB];
      [[unroll]] for (int j = 0; j < KB; ++j) kss[j] = 0.0;
      [[unroll]] for (int t = 0; t < (QK_ROPE ? DL / 2 : DL); ++t) {
        const int c = lane + t * LANES, h = DL / 2;
        float ka[KB], kb2[KB];
        [[unroll]] for (int j = 0; j < KB; ++j) {
          ka[j] = K_AT(kAt[j] + t * LANES);
          kss[j] += ka[j] * ka[j];
          ka[j] *= lanes_k_weight(c);
          if (QK_ROPE) {
            kb2[j] = K_AT(kAt[j] + (t + h) * LANES);
            kss[j] += kb2[j] * kb2[j];
            kb2[j] *= lanes_k_weight(c + DH / 2);
            lanes_rotate(ka[j], kb2[j], min(kb + j, p.Nk - 1), c);
          }
        }
        [[unroll]] for (int i = 0; i < QPS; ++i)
          [[unroll]] for (int j = 0; j < KB; ++j) {
            s[i * KB + j] = fma(qv[i * DL + t], ka[j], s[i * KB + j]);
            if (QK_ROPE) s[i * KB + j] = fma(qv[i * DL + t + h], kb2[j], s[i * KB + j]);
          }
      }
      [[unroll]] for (int i = 0; i < QPS * KB; ++i) s[i] = subgroupAdd(s[i]);
      if (QK_NORM)
        [[unroll]] for (int j = 0; j < KB; ++j) {
          const float r = qk_rstd(subgroupAdd(kss[j]));
          [[unroll]] for (int i = 0; i < QPS; ++i) s[i * KB + j] *= r;
        }
    } else {
      [[unroll]] for (int t = 0; t < DL; ++t) {
        float kv[KB];
        [[unroll]] for (int j = 0; j < KB; ++j) kv[j] = K_AT(kAt[j] + t * LANES);
        [[unroll]] for (int i = 0; i < QPS; ++i)
          [[unroll]] for (int j = 0; j < KB; ++j) s[i * KB + j] = fma(qv[i * DL + t], kv[j], s[i * KB + j]);
      }
      [[unroll]] for (int i = 0; i < QPS * KB; ++i) s[i] = subgroupAdd(s[i]);
    }

    float correction[QPS];
    [[unroll]] for (int i = 0; i < QPS; ++i) {
      float blockMax = runMax[i];
      [[unroll]] for (int j = 0; j < KB; ++j) {
        const int key = kb + j;
        const bool valid = key < p.Nk && (!CAUSAL || key <= q0 + i);
        s[i * KB + j] = valid ? s[i * KB + j] * p.scaleLog2 : kNegLarge;
        blockMax = max(blockMax, s[i * KB + j]);
      }
      correction[i] = exp2(runMax[i] - blockMax);
      runMax[i] = blockMax;
      float sum = runSum[i] * correction[i];
      [[unroll]] for (int j = 0; j < KB; ++j) {
        const int key = kb + j;
        const bool valid = key < p.Nk && (!CAUSAL || key <= q0 + i);
        const float e = valid ? exp2(s[i * KB + j] - blockMax) : 0.0;
        s[i * KB + j] = e;
        sum += e;
      }
      runSum[i] = sum;
    }
    // Values: each lane's channels, one chain of KB multiply-adds per accumulator.
    [[unroll]] for (int t = 0; t < DL; ++t) {
      float vv[KB];
      [[unroll]] for (int j = 0; j < KB; ++j) vv[j] = V_AT(vAt[j] + t * LANES);
      [[unroll]] for (int i = 0; i < QPS; ++i) {
        float a = acc[i * DL + t] * correction[i];
        [[unroll]] for (int j = 0; j < KB; ++j) a = fma(s[i * KB + j], vv[j], a);
        acc[i * DL + t] = a;
      }
    }
  }

  [[unroll]] for (int i = 0; i < QPS; ++i) {
    const int q = q0 + i;
    if (q >= p.Nq) break;
    const float inv = runSum[i] > 0.0 ? 1.0 / runSum[i] : 0.0;
    const int base = b * p.oBatch + q * p.oStride + p.oOff + head * DH + lane;
    [[unroll]] for (int t = 0; t < DL; ++t) o[base + t * LANES] = TO_OUT(acc[i * DL + t] * inv);
  }
}
