#version 450
// Embedding lookup (nn.Embedding, CLIP's token_embedding): out[t][d] = table[ids[t]][d] for
// t < tokens, d < dim. Host side: engine/ops/embedding.cpp.
//
// The table is a texel buffer, so one kernel reads f32 and f16 tables alike (the view's format
// converts). A table larger than one binding is bound in row ranges, one dispatch each: an
// invocation writes only when its id falls in the bound rows; ids outside [0, vocab) get
// zeros from the dispatch flagged zeroInvalid (the first).
// W_QUANT: the table is a block-quantized matrix (q8 / q4 by W_BITS, shaders/quant.glsl), bound
// whole as 32-bit words (tableBase 0, one dispatch); a value is dequantized where it is read.
//! variant embedding W_QUANT=0
//! variant embedding_q_f32 W_QUANT=1
#extension GL_GOOGLE_include_directive : require
#include "common.glsl"
#include "quant.glsl"

layout(local_size_x_id = 0, local_size_y_id = 1, local_size_z_id = 2) in;
layout(constant_id = 3) const int W_BITS = 8;  // W_QUANT: 8 (q8) or 4 (q4)

#if W_QUANT
QUANT_WORDS(0, table)
#else
TEXEL_INPUT(0, table, 1)
#endif
layout(binding = 1) readonly buffer Ids { int ids[]; };
layout(binding = 2) writeonly buffer Out { float outv[]; };

layout(push_constant) uniform Push {
  int tokens, dim, vocab;
  int rowBegin, rowCount;  // table rows this dispatch sees
  int tableBase;           // texel of row rowBegin, element 0, in the bound view
  int zeroInvalid;
} p;

void main() {
  const uint group = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;  // 2-D grid, x fastest
  const uint i = group * gl_WorkGroupSize.x + gl_LocalInvocationID.x;
  if (i >= uint(p.tokens) * uint(p.dim)) return;
  const int t = int(i / uint(p.dim)), d = int(i % uint(p.dim));
  const int id = ids[t];
  if (id >= p.rowBegin && id < p.rowBegin + p.rowCount) {
#if W_QUANT
    // a row: its codes (dim / 4 or dim / 8 words), then its dim / 32 scales
    const int codeWords = W_BITS == 8 ? p.dim / 4 : p.dim / 8;
    const int row = (id - p.rowBegin) * QUANT_ROW_WORDS(p.dim / 4);
    const float s = uintBitsToFloat(word_table(row + codeWords + d / 32));
    const int code = W_BITS == 8 ? (int(word_table(row + d / 4)) << (24 - 8 * (d & 3))) >> 24
                                 : int((word_table(row + d / 8) >> (4 * (d & 7))) & 0xFu) - 8;
    outv[i] = float(code) * s;
#else
    outv[i] = fetch_table(p.tableBase + (id - p.rowBegin) * p.dim + d).x;
#endif
  } else if (p.zeroInvalid != 0 && (id < 0 || id >= p.vocab)) {
    outv[i] = 0.0;
  }
}
