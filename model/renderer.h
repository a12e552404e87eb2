// SPAR's renderer (reference: converter/spar_reference/spar.py SPAR.render): per rendered view,
// the decoder (transformer_decoder) over decoder_ln([RGB ray queries, scene tokens]), and the RGB
// head image_token_decoder = LN (no bias) -> Linear(D, 16*16*3, no bias) -> sigmoid, unpatchified.
//
//   RGB queries = target_pose_tokenizer2(patchify(rays)) + view_type_embedding[1]
//
// Views are decoded independently (each attends to its own queries and the scene tokens), so
// they are batched, a few at a time to bound activation memory.
#pragma once
#include <cstdint>
#include <vector>

#include "engine/engine.h"
#include "engine/recorder.h"
#include "model/spar_config.h"
#include "model/transformer_block.h"
#include "model/view_tokens.h"
#include "model/weight_set.h"

namespace spar {

// Device tensors a test may want to see (all [R, ...] for the views of one forward call).
struct RenderTrace {
  Tensor rgbQueries;  // [R, n, D]
  Tensor decoderIn;   // [R, n + S, D] after decoder_ln
  Tensor decoderOut;  // [R, n + S, D]
  Tensor rgbTokens;   // [R, n, D]
};

class Renderer {
 public:
  Renderer(Engine& engine, WeightSet& weights, const SparConfig& config, ViewTokenizer& tokenizer);

  // rays [R, 6, H, W] of the views to render, scene [S, D] -> rgb [R, 3, H, W] in [0, 1].
  // With a trace, all R views are decoded in one batch and the trace tensors are allocated.
  void forward(Recorder& rec, const Tensor& rays, const Tensor& scene, const Tensor& rgb, TransformerWorkspace& ws,
               RenderTrace* trace = nullptr);

  // Views decoded per batch.
  static constexpr int64_t kViewsPerBatch = 4;

 private:
  void batch(Recorder& rec, const Tensor& rays, const Tensor& scene, const Tensor& rgb, TransformerWorkspace& ws,
             RenderTrace* trace);

  Engine& engine_;
  WeightSet& weights_;
  const SparConfig& config_;
  ViewTokenizer& tokenizer_;
  TransformerBlockOptions options_;
  std::vector<TransformerBlock> blocks_;
  Tensor lnW_, viewType1_, headLnW_, headW_;
};

}  // namespace spar
