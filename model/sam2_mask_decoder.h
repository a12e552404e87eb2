// SAM2.1's prompt encoder (mask branch) and mask decoder as SPAR's refinement runs them
// (official SAM2ImagePredictor.predict with mask_input and multimask_output; reference
// reference/spar_reference/sam2.py mask_prompt, prompt_dense, two_way_transformer,
// mask_decoder), on the engine:
//
//   prompt   P(dynamic) of a view [H, W] -> 20 * (P > 0.5) - 10, bilinear to 256 x 256
//   dense    Conv k2s2 -> LayerNorm2d -> GELU -> Conv k2s2 -> LayerNorm2d -> GELU -> Conv 1x1
//   tokens   [obj_score, iou, 4 mask tokens] through the two-way transformer (2 layers of
//            self-attention, token->image, MLP, image->token; LayerNorm 1e-5) over
//            image_embed + dense with the dense random-Fourier PE; the final token->image
//   upscale  ConvT x2 + feat_s1 -> LayerNorm2d -> GELU -> ConvT x2 + feat_s0 -> GELU
//   masks    hypernetworks 1-3 of the mask tokens . upscaled; IoU = sigmoid(head)[1:4]
//
// Channel-last tokens throughout (LayerNorm2d is then the LayerNorm of a row); the dense PE
// and the tokens are input-independent and made once. Weights by official key under `prefix`.
#pragma once
#include <string>

#include "engine/engine.h"
#include "engine/recorder.h"
#include "model/sam2_config.h"
#include "model/sam2_image_encoder.h"
#include "model/transformer_block.h"

namespace spar {

struct Sam2MaskResult {
  Tensor prompt;        // [256 * 256] the mask prompt's logits as the prompt encoder reads them
  Tensor dense;         // [64 * 64, d] the dense prompt embedding
  Tensor tokensOut;     // [6, d] the transformer's tokens
  Tensor upscaled;      // [256 * 256, d / 8]
  Tensor iou;           // [1, 3] the multimask outputs' IoU predictions
  Tensor chosenLogits;  // [256 * 256] low-resolution logits of the mask of the highest IoU
  Tensor allLogits;     // [256 * 256, 3] all three (only with allMasks)
};

// The refinement's two small kernels (model/shaders/sam2_decoder.comp):
// y = x > t ? 1 : 0 elementwise (f32, the same element count; the binary prompt at t = 0.5,
// the refined mask at t = 0).
void sam2Threshold(Recorder& rec, const Tensor& x, float t, const Tensor& y);
// counts [V] i32 = the number of P(dynamic) > 0.5 of each view of probs [V, H, W]; counts are
// zeroed here (a host write) before the dispatch is recorded.
void sam2CountDynamic(Recorder& rec, const Tensor& probs, const Tensor& counts);

class Sam2MaskDecoder {
 public:
  Sam2MaskDecoder(Engine& engine, const Sam2Config& config, WeightLookup weights, std::string prefix = "sam2.");

  // probs: [V, H, W] P(dynamic); the prompt is view `view`'s.
  Sam2MaskResult decode(Recorder& rec, const Sam2ImageFeatures& features, const Tensor& probs, int64_t view,
                        bool allMasks = false) const;

 private:
  // decode()'s parts, in order.
  void prompt(Recorder& rec, const Tensor& probs, int64_t view, Sam2MaskResult& r) const;
  Tensor twoWay(Recorder& rec, const Sam2ImageFeatures& f, Sam2MaskResult& r) const;
  void upscale(Recorder& rec, const Sam2ImageFeatures& f, const Tensor& keys, Sam2MaskResult& r) const;
  void heads(Recorder& rec, Sam2MaskResult& r, bool allMasks) const;
  Tensor weight(const std::string& name) const;
  Tensor attention(Recorder& rec, const std::string& p, const Tensor& q, const Tensor& k, const Tensor& v) const;
  Tensor linearOf(Recorder& rec, const std::string& p, const Tensor& x, int64_t out, Activation act = Activation::None) const;
  Tensor mlp3(Recorder& rec, const std::string& p, const Tensor& x, int64_t out, Activation last) const;

  Engine& engine_;
  Sam2Config config_;
  WeightLookup weights_;
  std::string prefix_;
  Tensor densePe_;  // [64 * 64, d]
  Tensor tokens_;   // [6, d]
};

}  // namespace spar
