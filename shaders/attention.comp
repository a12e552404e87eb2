#version 450
// Fused multi-head attention, o = softmax(q k^T * scale (+ causal mask)) v, per head,
// with an online softmax over blocks of KB keys: the N x N score matrix never exists.
// Host side: engine/ops/attention.cpp.
//
// q, k, v are RGBA texel views (4 consecutive head channels); they may all be the same
// fused qkv tensor at different column offsets. One invocation owns QPI queries of one
// head and keeps their DH-wide accumulators in registers; no shared memory (see gemm.comp).
// Numerics: running max starts at -FLT_MAX/2 (never -inf, so exp2 of a difference is never
// NaN), masked keys contribute exactly 0, and the final division is guarded.
//
// SHARED_KEYS (the attention_sk_* variants): the workgroup is one subgroup of LANES invocations,
// and they share each block's keys: lane l fetches the k and v texels of keys l, LANES + l, ...
// and every lane takes a key's values from its lane by a shuffle, so one fetch serves LANES keys
// (on llvmpipe a texel fetch is a call that spills every register: shaders/gemm.comp).
//
// QK_NORM / QK_ROPE (shaders/attention_prep.glsl): the queries' 1 / rms are found once, and
// their texels are normed and rotated as they are fetched, as in the plain kernel, per block;
// each lane weights and rotates the k texels it fetches (its own keys) and sums their squares,
// and every score is multiplied by its key's 1 / rms at the end of the block. With RoPE the
// channels go in pairs (texels u and u + DH / 8).
//! variant attention_f32 OUT_F16=0
//! variant attention_f16out OUT_F16=1
//! variant attention_sk_f32 OUT_F16=0 SHARED_KEYS=1
//! variant attention_sk_f16out OUT_F16=1 SHARED_KEYS=1
//! variant attention_prep_f32 OUT_F16=0 QK_PREP_BINDINGS=1
//! variant attention_prep_f16out OUT_F16=1 QK_PREP_BINDINGS=1
//! variant attention_sk_prep_f32 OUT_F16=0 SHARED_KEYS=1 QK_PREP_BINDINGS=1
//! variant attention_sk_prep_f16out OUT_F16=1 SHARED_KEYS=1 QK_PREP_BINDINGS=1
#extension GL_GOOGLE_include_directive : require
#ifndef SHARED_KEYS
#define SHARED_KEYS 0
#endif
#if SHARED_KEYS
#extension GL_KHR_shader_subgroup_shuffle : require
#endif
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const int DH = 64;   // head dimension (multiple of 4)
layout(constant_id = 4) const int QPI = 8;   // queries per invocation
layout(constant_id = 5) const int KB = 16;   // keys per block (multiple of 4)
layout(constant_id = 6) const bool CAUSAL = false;
layout(constant_id = 7) const int LANES = 8;  // SHARED_KEYS: the workgroup's x size, one full subgroup (KB a multiple)

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

void main() {
  const int q0 = int(gl_GlobalInvocationID.x) * QPI;
  const int head = int(gl_WorkGroupID.y);
  const int b = int(gl_WorkGroupID.z);
#if SHARED_KEYS
  // Every lane stays to the end (the shuffles need them all): the last workgroup's queries past
  // Nq compute clamped duplicates that are not stored, and with a causal mask every lane walks
  // the keys of the workgroup's last query, masking its own.
  const int KT = KB / LANES;  // key texels a lane fetches per channel group
  const int keyLane = int(gl_SubgroupInvocationID);
#define KEY_OF(t) ((t) * LANES + keyLane)
#define KEY_TEXEL(tex, j) subgroupShuffle(tex[(j) / LANES], (j) % LANES)
  const int lastQuery = (int(gl_WorkGroupID.x) + 1) * LANES * QPI;
#else
  if (q0 >= p.Nq) return;
  const int KT = KB;
#define KEY_OF(t) (t)
#define KEY_TEXEL(tex, j) tex[j]
  const int lastQuery = q0 + QPI;
#endif

  int qTexel[QPI];
  [[unroll]] for (int i = 0; i < QPI; ++i)
    qTexel[i] = (b * p.qBatch + min(q0 + i, p.Nq - 1) * p.qStride + p.qOff + head * DH) / 4;
  const int kBase = (b * p.kBatch + p.kOff + head * DH) / 4, kRow = p.kStride / 4;
  const int vBase = (b * p.vBatch + p.vOff + head * DH) / 4, vRow = p.vStride / 4;

  // QK_NORM: the queries' 1 / rms, once; their texels are prepared as they are fetched below
  // (a prepared copy of the heads, indexed by the loop's texel, took llvmpipe 2.7-3.8 s to compile)
  float qr[QPI];
  [[unroll]] for (int i = 0; i < QPI; ++i) {
    float ss = 0.0;
    if (QK_NORM)
      for (int u = 0; u < DH / 4; ++u) {
        const vec4 x = fetch_Q(qTexel[i] + u);
        ss += dot(x, x);
      }
    qr[i] = QK_NORM ? qk_rstd(ss) : 1.0;
  }

  float runMax[QPI], runSum[QPI], acc[QPI * DH];
  [[unroll]] for (int i = 0; i < QPI; ++i) { runMax[i] = kNegLarge; runSum[i] = 0.0; }
  [[unroll]] for (int i = 0; i < QPI * DH; ++i) acc[i] = 0.0;

  // With a causal mask no query here sees keys past the last query.
  const int kEnd = CAUSAL ? min(p.Nk, lastQuery) : p.Nk;
  for (int kb = 0; kb < kEnd; kb += KB) {
    int kTexel[KT], vTexel[KT];
    [[unroll]] for (int t = 0; t < KT; ++t) {
      const int key = min(kb + KEY_OF(t), p.Nk - 1);
      kTexel[t] = kBase + key * kRow;
      vTexel[t] = vBase + key * vRow;
    }
    // Scores: per group of 4 head channels every fetch first (QPI queries, KT keys), then the
    // QPI x KB dot-product steps.
    float s[QPI * KB];
    [[unroll]] for (int i = 0; i < QPI * KB; ++i) s[i] = 0.0;
    if (QK_PREP) {
      // Texels u (and, with RoPE, u + DH / 8) of the lane's own keys, weighted and rotated; the
      // keys' sums of squares (QK_NORM) scale the scores below.
      const int units = QK_ROPE ? DH / 8 : DH / 4, h = DH / 8;
      float kss[KT];
      [[unroll]] for (int t = 0; t < KT; ++t) kss[t] = 0.0;
      for (int u = 0; u < units; ++u) {
        const vec4 wa = qk_weight(1, u), wb = QK_ROPE ? qk_weight(1, u + h) : vec4(1.0);
        vec4 ka[KT], kb2[KT];
        [[unroll]] for (int t = 0; t < KT; ++t) {
          ka[t] = fetch_K(kTexel[t] + u);
          kss[t] += dot(ka[t], ka[t]);
          ka[t] *= wa;
          if (QK_ROPE) {
            kb2[t] = fetch_K(kTexel[t] + u + h);
            kss[t] += dot(kb2[t], kb2[t]);
            kb2[t] *= wb;
            qk_rotate(ka[t], kb2[t], min(kb + KEY_OF(t), p.Nk - 1), u);
          }
        }
        // the queries' texels u (and u + DH / 8), normed (head * rstd * weight) and rotated
        vec4 qa[QPI], qb[QPI];
        [[unroll]] for (int i = 0; i < QPI; ++i) {
          qa[i] = fetch_Q(qTexel[i] + u) * qr[i] * qk_weight(0, u);
          if (QK_ROPE) {
            qb[i] = fetch_Q(qTexel[i] + u + h) * qr[i] * qk_weight(0, u + h);
            qk_rotate(qa[i], qb[i], min(q0 + i, p.Nq - 1), u);
          }
        }
        [[unroll]] for (int j = 0; j < KB; ++j) {
          const vec4 kv = KEY_TEXEL(ka, j);
          [[unroll]] for (int i = 0; i < QPI; ++i) {
            const vec4 qv = qa[i];
            s[i * KB + j] = fma(qv.w, kv.w, fma(qv.z, kv.z, fma(qv.y, kv.y, fma(qv.x, kv.x, s[i * KB + j]))));
          }
          if (QK_ROPE) {
            const vec4 kv2 = KEY_TEXEL(kb2, j);
            [[unroll]] for (int i = 0; i < QPI; ++i) {
              const vec4 qv = qb[i];
              s[i * KB + j] = fma(qv.w, kv2.w, fma(qv.z, kv2.z, fma(qv.y, kv2.y, fma(qv.x, kv2.x, s[i * KB + j]))));
            }
          }
        }
      }
      if (QK_NORM) {
        float rk[KT];
        [[unroll]] for (int t = 0; t < KT; ++t) rk[t] = qk_rstd(kss[t]);
        [[unroll]] for (int j = 0; j < KB; ++j) {
          const float r = KEY_TEXEL(rk, j);
          [[unroll]] for (int i = 0; i < QPI; ++i) s[i * KB + j] *= r;
        }
      }
    } else
    for (int d4 = 0; d4 < DH / 4; ++d4) {
      vec4 qv[QPI];
      [[unroll]] for (int i = 0; i < QPI; ++i) qv[i] = fetch_Q(qTexel[i] + d4);
      vec4 kt[KT];
      [[unroll]] for (int t = 0; t < KT; ++t) kt[t] = fetch_K(kTexel[t] + d4);
      [[unroll]] for (int j = 0; j < KB; ++j) {
        const vec4 kv = KEY_TEXEL(kt, j);
        [[unroll]] for (int i = 0; i < QPI; ++i)
          s[i * KB + j] = fma(qv[i].w, kv.w, fma(qv[i].z, kv.z, fma(qv[i].y, kv.y, fma(qv[i].x, kv.x, s[i * KB + j]))));
      }
    }
    [[unroll]] for (int i = 0; i < QPI; ++i) {
      float blockMax = runMax[i];
      [[unroll]] for (int j = 0; j < KB; ++j) {
        const int key = kb + j;
        const bool valid = key < p.Nk && (!CAUSAL || key <= q0 + i);
        s[i * KB + j] = valid ? s[i * KB + j] * p.scaleLog2 : kNegLarge;
        blockMax = max(blockMax, s[i * KB + j]);
      }
      const float correction = exp2(runMax[i] - blockMax);
      runMax[i] = blockMax;
      float sum = runSum[i] * correction;
      [[unroll]] for (int j = 0; j < KB; ++j) {
        const int key = kb + j;
        const bool valid = key < p.Nk && (!CAUSAL || key <= q0 + i);
        const float e = valid ? exp2(s[i * KB + j] - blockMax) : 0.0;
        s[i * KB + j] = e;
        sum += e;
      }
      runSum[i] = sum;
      [[unroll]] for (int d = 0; d < DH; ++d) acc[i * DH + d] *= correction;
    }
    // Values: per group of 4 head channels every fetch first (KT keys), then each accumulator
    // takes one chain of KB fmas per load and store: with QPI x DH accumulators mostly in spilled
    // registers, that traffic, not the arithmetic, bounds this loop on a CPU device.
    [[unroll]] for (int d4 = 0; d4 < DH / 4; ++d4) {
      vec4 vt[KT];
      [[unroll]] for (int t = 0; t < KT; ++t) vt[t] = fetch_V(vTexel[t] + d4);
      vec4 vv[KB];
      [[unroll]] for (int j = 0; j < KB; ++j) vv[j] = KEY_TEXEL(vt, j);
      [[unroll]] for (int i = 0; i < QPI; ++i)
        [[unroll]] for (int c = 0; c < 4; ++c) {
          float a = acc[i * DH + d4 * 4 + c];
          [[unroll]] for (int j = 0; j < KB; ++j) a = fma(s[i * KB + j], vv[j][c], a);
          acc[i * DH + d4 * 4 + c] = a;
        }
    }
  }

  [[unroll]] for (int i = 0; i < QPI; ++i) {
    const int q = q0 + i;
    if (q >= p.Nq) break;
    const float inv = runSum[i] > 0.0 ? 1.0 / runSum[i] : 0.0;
    const int base = b * p.oBatch + q * p.oStride + p.oOff + head * DH;
    [[unroll]] for (int d = 0; d < DH; ++d) o[base + d] = TO_OUT(acc[i * DH + d] * inv);
  }
}
