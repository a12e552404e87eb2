// Embedding lookup (nn.Embedding: rows of a table picked by integer ids) on
// shaders/embedding.comp: CLIP's token embedding, and picking rows of any [V, D] tensor by
// index (CLIP's pooling at the end token).
#pragma once
#include "engine/recorder.h"

namespace spar {

// out[t, :] = table[ids[t], :]. table: [V, D] f32 or f16; ids: I32 with T elements (any
// shape); out: f32 with T * D elements. An id outside [0, V) gives a row of zeros. A table
// larger than one texel binding is read in row ranges (one dispatch each).
void embedding(Recorder& rec, const Tensor& table, const Tensor& ids, const Tensor& out);

}  // namespace spar
