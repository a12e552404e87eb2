#version 450
// Fused multi-head attention for GPUs, o = softmax(q k^T * scale (+ causal mask)) v per head,
// with keys and values staged in shared memory. Host side: engine/ops/attention.cpp (the
// llvmpipe family is attention.comp: register blocks, no shared memory).
//
// A workgroup of BQ invocations takes BQ consecutive queries of one head, one query each
// (its DH-wide q and output accumulator in registers). Per block of BKEYS keys the workgroup
// copies the keys' k and v rows into shared memory once; every invocation then reads them
// all (the same address across the workgroup: a broadcast), scores its query against the
// block, and folds it into its output with an online softmax, KC keys at a time. Same numerics as
// attention.comp: running max from -FLT_MAX/2 (never -inf), masked keys contribute exactly
// 0, guarded final division. Bindings and push constants are attention.comp's. With QK_NORM /
// QK_ROPE (shaders/attention_prep.glsl) each query's head is prepared in registers, and each
// block's k rows in shared memory after they arrive.
//! variant attention_tiled_f32 OUT_F16=0
//! variant attention_tiled_f16out OUT_F16=1
//! variant attention_tiled_prep_f32 OUT_F16=0 QK_PREP_BINDINGS=1
//! variant attention_tiled_prep_f16out OUT_F16=1 QK_PREP_BINDINGS=1
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;  // BQ x 1 x 1
layout(constant_id = 3) const int DH = 64;      // head dimension (multiple of 4)
layout(constant_id = 4) const int BKEYS = 32;   // keys per shared-memory block (a multiple of 4)
layout(constant_id = 5) const bool CAUSAL = false;

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
const int KC = BKEYS % 8 == 0 ? 8 : 4;  // keys per unrolled chunk (divides BKEYS)
shared vec4 blockK[BKEYS * D4];
shared vec4 blockV[BKEYS * D4];

void main() {
  const int BQ = int(gl_WorkGroupSize.x);
  const int q0 = int(gl_WorkGroupID.x) * BQ;
  const int q = q0 + int(gl_LocalInvocationID.x);
  const int head = int(gl_WorkGroupID.y);
  const int b = int(gl_WorkGroupID.z);
  const bool live = q < p.Nq;

  vec4 qv[D4], acc[D4];
  const int qTexel = (b * p.qBatch + min(q, p.Nq - 1) * p.qStride + p.qOff + head * DH) / 4;
  [[unroll]] for (int d = 0; d < D4; ++d) {
    qv[d] = fetch_Q(qTexel + d);
    acc[d] = vec4(0.0);
  }
  if (QK_PREP) QK_PREP_HEAD(qv, 0, min(q, p.Nq - 1))
  const int kBase = (b * p.kBatch + p.kOff + head * DH) / 4, kRow = p.kStride / 4;
  const int vBase = (b * p.vBatch + p.vOff + head * DH) / 4, vRow = p.vStride / 4;
  float runMax = kNegLarge, runSum = 0.0;

  // With a causal mask no query of this workgroup sees keys past its last query.
  const int kEnd = CAUSAL ? min(p.Nk, q0 + BQ) : p.Nk;
  for (int kb = 0; kb < kEnd; kb += BKEYS) {
    for (int i = int(gl_LocalInvocationID.x); i < BKEYS * D4; i += BQ) {
      const int key = kb + i / D4, d = i % D4;
      const bool inside = key < p.Nk;
      blockK[i] = inside ? fetch_K(kBase + key * kRow + d) : vec4(0.0);
      blockV[i] = inside ? fetch_V(vBase + key * vRow + d) : vec4(0.0);
    }
    barrier();
    if (QK_PREP) {  // each k row of the block normed and rotated once, by one invocation
      for (int r = int(gl_LocalInvocationID.x); r < BKEYS && kb + r < p.Nk; r += BQ) {
        vec4 row[D4];
        [[unroll]] for (int d = 0; d < D4; ++d) row[d] = blockK[r * D4 + d];
        QK_PREP_HEAD(row, 1, kb + r)
        [[unroll]] for (int d = 0; d < D4; ++d) blockK[r * D4 + d] = row[d];
      }
      barrier();
    }
    // The block in chunks of KC keys: scores in registers, then one online-softmax step per
    // chunk. Only a chunk is unrolled, so the code (and a driver's compile time: llvmpipe took
    // 30 s for a 32-key block unrolled whole) stays that of KC keys whatever BKEYS is; the
    // extra rescale of acc per chunk costs DH/4 multiplies per KC keys (a sixteenth of the
    // block's multiply-adds at KC = 8).
    const int chunkEnd = min(BKEYS, kEnd - kb);
    [[dont_unroll]] for (int j0 = 0; j0 < chunkEnd; j0 += KC) {
      float s[KC];
      float chunkMax = runMax;
      [[unroll]] for (int j = 0; j < KC; ++j) {
        float dotv = 0.0;
        [[unroll]] for (int d = 0; d < D4; ++d) {
          const vec4 kv = blockK[(j0 + j) * D4 + d];
          dotv = fma(qv[d].w, kv.w, fma(qv[d].z, kv.z, fma(qv[d].y, kv.y, fma(qv[d].x, kv.x, dotv))));
        }
        const int key = kb + j0 + j;
        const bool valid = key < p.Nk && (!CAUSAL || key <= q);
        s[j] = valid ? dotv * p.scaleLog2 : kNegLarge;
        chunkMax = max(chunkMax, s[j]);
      }
      const float correction = exp2(runMax - chunkMax);
      runMax = chunkMax;
      float sum = runSum * correction;
      [[unroll]] for (int j = 0; j < KC; ++j) {
        const int key = kb + j0 + j;
        const bool valid = key < p.Nk && (!CAUSAL || key <= q);
        s[j] = valid ? exp2(s[j] - chunkMax) : 0.0;
        sum += s[j];
      }
      runSum = sum;
      [[unroll]] for (int d = 0; d < D4; ++d) acc[d] *= correction;
      [[unroll]] for (int j = 0; j < KC; ++j)
        [[unroll]] for (int d = 0; d < D4; ++d) acc[d] = fma(vec4(s[j]), blockV[(j0 + j) * D4 + d], acc[d]);
    }
    barrier();
  }

  if (!live) return;
  const float inv = runSum > 0.0 ? 1.0 / runSum : 0.0;
  const int base = b * p.oBatch + q * p.oStride + p.oOff + head * DH;
  [[unroll]] for (int d = 0; d < D4; ++d)
    [[unroll]] for (int c = 0; c < 4; ++c) o[base + d * 4 + c] = TO_OUT(acc[d][c] * inv);
}
