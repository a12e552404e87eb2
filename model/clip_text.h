// CLIP's text encoder (the ViT-B/32 text tower SPAR's labels use) on the engine.
// Reference: reference/spar_reference/clip_text.py (CLIPTextEncoder), OpenAI's key layout under
// "clip." in the packed file (converter/FORMAT.md):
//
//   ids [P, 77] (text/bpe_tokenizer.h)
//     -> token_embedding[ids] + positional_embedding          (embedding op + add)
//     -> layers x TransformerBlock (options clipText: LayerNorm with bias, biases, causal
//        attention, QuickGELU), weights clip.transformer.resblocks.<i>.{ln_1, attn.in_proj_*,
//        attn.out_proj, ln_2, mlp.c_fc, mlp.c_proj}
//     -> the row at the end token (argmax of the ids, as CLIP) -> ln_final
//     -> @ text_projection [W, E]                             -> embeddings [P, E] (not normalized)
//
// Two shortcuts that change nothing but time: the sequence is cut after the last end token of
// the batch (attention is causal, so later positions never reach a pooled row), and ln_final
// runs on the pooled rows only (LayerNorm is per row). text_projection is transposed once at
// construction (on the host) so that the projection is the linear op's x W^T.
#pragma once
#include <nlohmann/json.hpp>

#include <cstdint>
#include <string>
#include <vector>

#include "engine/engine.h"
#include "engine/recorder.h"
#include "model/transformer_block.h"
#include "model/weight_set.h"

namespace spar {

struct ClipTextConfig {
  int64_t width = 512, layers = 12, heads = 8, contextLength = 77, vocabSize = 49408, embedDim = 512;
  double lnEps = 1e-5;
  int64_t headDim() const { return heads > 0 ? width / heads : 0; }

  // The packed config's "clip" object (SparConfig.raw["clip"]); throws one line naming a
  // missing or unusable field.
  static ClipTextConfig fromJson(const nlohmann::json& clip, const std::string& where);
};

class ClipTextEncoder {
 public:
  static constexpr const char* kPrefix = "clip.";

  // Requires every clip.* tensor with its expected shape (a missing or mis-shaped one is a
  // one-line spar::Error naming it).
  ClipTextEncoder(Engine& engine, WeightSet& weights, const ClipTextConfig& config);

  // ids: [P, contextLength] row-major, as BpeTokenizer::tokenize gives them (every id in
  // [0, vocabSize)); embeddings: f32 [P, embedDim], written. Records dispatches into rec (the
  // ids are uploaded now); ws grows to P * (last end position + 1) tokens if smaller.
  void forward(Recorder& rec, const std::vector<int32_t>& ids, const Tensor& embeddings, TransformerWorkspace& ws);

  // Where CLIP pools a row: the first position of its largest id (the end token).
  static int64_t endPosition(const int32_t* row, int64_t length);

  const ClipTextConfig& config() const { return config_; }
  const TransformerBlockOptions& blockOptions() const { return options_; }

 private:
  Engine& engine_;
  ClipTextConfig config_;
  TransformerBlockOptions options_;
  Tensor tokenEmbedding_;       // [V, W] (f32, or f16 under an fp16 weight set)
  Tensor positional_;           // [77, W] f32
  Tensor lnFinalW_, lnFinalB_;  // [W]
  Tensor projection_;           // [E, W]: text_projection transposed
  std::vector<TransformerBlock> blocks_;
};

}  // namespace spar
