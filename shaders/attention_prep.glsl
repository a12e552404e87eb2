// What an attention kernel does to the q and k heads as it reads them (attention.comp,
// attention_tiled.comp): the RMS norm of each head (QK_NORM: SPAR's q_norm / k_norm) and then
// rotary position embedding (QK_ROPE: DINOv3), the same values shaders/norm.comp's per-head
// RMSNorm and shaders/rope.comp would leave in the fused qkv tensor, without those two
// dispatches. Host side: engine/ops/attention.cpp (QkPrep). Included after the kernel's Push
// block, which ends with qkEps and ropePrefix, and its DH.
//
// RoPE pairs channel c with c + DH / 2: a head's texel u with texel u + DH / 8, both vec4s.
// The norm is linear in the head after its sum of squares, so a kernel may rotate k * weight
// and multiply its scores by k's 1 / rms afterwards (attention.comp does).
// The *_prep variants (QK_PREP_BINDINGS=1) have the bindings and constants; the others none of
// them (a device with 4 storage bindings a kernel still runs those), and their QK_PREP is false.
#ifndef QK_PREP_BINDINGS
#define QK_PREP_BINDINGS 0
#endif
const int QK_DH = int(DH);  // the head dimension as an int (attention_coopmat.comp's DH is a uint)
#if QK_PREP_BINDINGS
layout(constant_id = 12) const bool QK_NORM = false;
layout(constant_id = 13) const bool QK_ROPE = false;
TEXEL_INPUT(4, QK_NORM_W, 4)  // [2, DH]: q_norm's weight, then k_norm's (bound to q when unused)
TEXEL_INPUT(5, ROPE_SIN, 4)   // [tokens - ropePrefix, DH] (bound to q when unused)
TEXEL_INPUT(6, ROPE_COS, 4)

// 1 / rms of a head from its sum of squares: norm.comp's formula (0 for an all-zero head at eps 0).
float qk_rstd(float sumSquares) {
  const float ms = sumSquares / float(QK_DH) + p.qkEps;
  return ms > 0.0 ? 1.0 / sqrt(ms) : 0.0;
}

// The norm weight of texel u of a q (which 0) or k (which 1) head.
vec4 qk_weight(int which, int u) { return QK_NORM ? fetch_QK_NORM_W(which * (QK_DH / 4) + u) : vec4(1.0); }

// Rotates texels u and u + DH / 8 of the head of `token` (rope.comp's x cos + rotate_half(x) sin);
// the first ropePrefix tokens (DINOv3's class and storage tokens) stay as they are.
void qk_rotate(inout vec4 a, inout vec4 b, int token, int u) {
  if (!QK_ROPE || token < p.ropePrefix) return;
  const int row = (token - p.ropePrefix) * (QK_DH / 4), h = QK_DH / 8;
  const vec4 na = a * fetch_ROPE_COS(row + u) - b * fetch_ROPE_SIN(row + u);
  const vec4 nb = b * fetch_ROPE_COS(row + u + h) + a * fetch_ROPE_SIN(row + u + h);
  a = na;
  b = nb;
}
#else
const bool QK_NORM = false, QK_ROPE = false;
float qk_rstd(float sumSquares) { return 1.0; }
vec4 qk_weight(int which, int u) { return vec4(1.0); }
void qk_rotate(inout vec4 a, inout vec4 b, int token, int u) {}
#endif

const bool QK_PREP = QK_NORM || QK_ROPE;

// A whole head in registers (an array of DH / 4 texels), normed and rotated in place (a macro:
// glslang matches no function parameter to an array sized by a specialization constant).
#define QK_PREP_HEAD(head, which, token)                                                           \
  {                                                                                              \
    if (QK_NORM) {                                                                               \
      float ss_ = 0.0;                                                                           \
      [[unroll]] for (int u_ = 0; u_ < QK_DH / 4; ++u_) ss_ += dot(head[u_], head[u_]);            \
      const float r_ = qk_rstd(ss_);                                                             \
      [[unroll]] for (int u_ = 0; u_ < QK_DH / 4; ++u_) head[u_] = head[u_] * r_ * qk_weight(which, u_); \
    }                                                                                            \
    if (QK_ROPE) {                                                                               \
      [[unroll]] for (int u_ = 0; u_ < QK_DH / 8; ++u_) qk_rotate(head[u_], head[u_ + QK_DH / 8], token, u_); \
    }                                                                                            \
  }
