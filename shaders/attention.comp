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
//! variant attention_f32 OUT_F16=0
//! variant attention_f16out OUT_F16=1
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const int DH = 64;   // head dimension (multiple of 4)
layout(constant_id = 4) const int QPI = 8;   // queries per invocation
layout(constant_id = 5) const int KB = 16;   // keys per block (multiple of 4)
layout(constant_id = 6) const bool CAUSAL = false;

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
} p;

const float kNegLarge = -3.4028235e38 / 2.0;

void main() {
  const int q0 = int(gl_GlobalInvocationID.x) * QPI;
  const int head = int(gl_WorkGroupID.y);
  const int b = int(gl_WorkGroupID.z);
  if (q0 >= p.Nq) return;

  int qTexel[QPI];
  [[unroll]] for (int i = 0; i < QPI; ++i)
    qTexel[i] = (b * p.qBatch + min(q0 + i, p.Nq - 1) * p.qStride + p.qOff + head * DH) / 4;
  const int kBase = (b * p.kBatch + p.kOff + head * DH) / 4, kRow = p.kStride / 4;
  const int vBase = (b * p.vBatch + p.vOff + head * DH) / 4, vRow = p.vStride / 4;

  float runMax[QPI], runSum[QPI], acc[QPI * DH];
  [[unroll]] for (int i = 0; i < QPI; ++i) { runMax[i] = kNegLarge; runSum[i] = 0.0; }
  [[unroll]] for (int i = 0; i < QPI * DH; ++i) acc[i] = 0.0;

  // With a causal mask no query of this invocation sees keys past its last query.
  const int kEnd = CAUSAL ? min(p.Nk, q0 + QPI) : p.Nk;
  for (int kb = 0; kb < kEnd; kb += KB) {
    float s[QPI * KB];
    [[unroll]] for (int i = 0; i < QPI * KB; ++i) s[i] = 0.0;
    for (int d4 = 0; d4 < DH / 4; ++d4) {
      vec4 qv[QPI];
      [[unroll]] for (int i = 0; i < QPI; ++i) qv[i] = fetch_Q(qTexel[i] + d4);
      [[unroll]] for (int j = 0; j < KB; ++j) {
        vec4 kv = fetch_K(kBase + min(kb + j, p.Nk - 1) * kRow + d4);
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
    // Keys advance 4 at a time in a loop; head channels are unrolled, so every
    // accumulator index is a compile-time constant, and each accumulator takes a chain
    // of 4 fmas per load/store: with QPI x DH accumulators mostly in spilled registers,
    // that traffic, not the arithmetic, is what bounds this loop on a CPU device.
    [[unroll]] for (int j0 = 0; j0 < KB; j0 += 4) {
      float w[QPI * 4];
      [[unroll]] for (int i = 0; i < QPI; ++i)
        [[unroll]] for (int u = 0; u < 4; ++u) w[i * 4 + u] = s[i * KB + j0 + u];
      int vTexel[4];
      [[unroll]] for (int u = 0; u < 4; ++u) vTexel[u] = vBase + min(kb + j0 + u, p.Nk - 1) * vRow;
      [[unroll]] for (int d4 = 0; d4 < DH / 4; ++d4) {
        const vec4 v0 = fetch_V(vTexel[0] + d4), v1 = fetch_V(vTexel[1] + d4);
        const vec4 v2 = fetch_V(vTexel[2] + d4), v3 = fetch_V(vTexel[3] + d4);
        [[unroll]] for (int i = 0; i < QPI; ++i)
          [[unroll]] for (int c = 0; c < 4; ++c) {
            const int a = i * DH + d4 * 4 + c;
            acc[a] = fma(w[i * 4 + 3], v3[c], fma(w[i * 4 + 2], v2[c], fma(w[i * 4 + 1], v1[c], fma(w[i * 4], v0[c], acc[a]))));
          }
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
