// SPAR's renderer (reference: reference/spar_reference/spar.py SPAR.render): per rendered view,
// the decoder (transformer_decoder) over decoder_ln([RGB ray queries, semantic ray queries (models
// with semantic decoding), scene tokens]), the RGB head image_token_decoder = LN (no bias) ->
// Linear(D, 16*16*3, no bias) -> sigmoid, unpatchified, and on request the semantic head
// semantic_token_decoder = LN -> Linear(D, 2D) -> GELU -> Linear(2D, 4D) -> GELU ->
// Linear(4D, 16*16*64) (no biases), unpatchified to 64 x H x W, bilinear x0.5, Conv1x1 64 -> C.
//
//   RGB queries      = target_pose_tokenizer2(patchify(rays)) + view_type_embedding[1]
//   semantic queries = target_pose_tokenizer_semantic(patchify(rays)) + view_type_embedding[1]
//
// The semantic queries take part in the decoder whenever the model decodes semantics (they change
// the RGB result through attention); the semantic head runs only when features are asked for.
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
  Tensor semanticQueries;  // [R, n, D] (semantic decoding only)
  Tensor decoderIn;   // [R, L, D] after decoder_ln, L = n (+ n) + S
  Tensor decoderOut;  // [R, L, D]
  Tensor rgbTokens;   // [R, n, D]
  Tensor semanticOutTokens;  // [R, n, D] (with features)
  Tensor semanticHidden;     // [R, 64, H, W] (with features)
};

class Renderer {
 public:
  Renderer(Engine& engine, WeightSet& weights, const SparConfig& config, ViewTokenizer& tokenizer);

  // rays [R, 6, H, W] of the views to render, scene [S, D] -> rgb [R, 3, H, W] in [0, 1];
  // features (optional, semantic decoding only): [R, C, H/2, W/2] semantic features.
  // With a trace, all R views are decoded in one batch and the trace tensors are allocated.
  void forward(Recorder& rec, const Tensor& rays, const Tensor& scene, const Tensor& rgb, TransformerWorkspace& ws,
               const Tensor& features = Tensor(), RenderTrace* trace = nullptr);
  bool semanticQueries() const { return semanticQueries_; }

  // Views decoded per batch.
  static constexpr int64_t kViewsPerBatch = 4;

 private:
  void batch(Recorder& rec, const Tensor& rays, const Tensor& scene, const Tensor& rgb, TransformerWorkspace& ws,
             const Tensor& features, RenderTrace* trace);
  void semanticHead(Recorder& rec, const Tensor& tokens, const Tensor& features, RenderTrace* trace);

  Engine& engine_;
  WeightSet& weights_;
  const SparConfig& config_;
  ViewTokenizer& tokenizer_;
  TransformerBlockOptions options_;
  std::vector<TransformerBlock> blocks_;
  Tensor lnW_, viewType1_, headLnW_, headW_;
  bool semanticQueries_ = false;
};

}  // namespace spar
