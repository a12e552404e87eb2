// Input tokens of the scene encoder: mlp_fuse over (image token, ray token) of each input view,
// then soft_with_pe gating by the motion probability (reference: reference/spar_reference/
// spar.py SPAR.forward "gating of the input tokens" and SPAR.gate). Gating kernel:
// model/shaders/token_gate.comp.
//
//   fused  = mlp_fuse(concat(img, ray)) + view_type_embedding[0]   mlp_fuse = LN(2D, no bias)
//            -> Linear(2D, D) -> SiLU -> Linear(D, D)
//   p      = avg_pool16(P(dynamic)) per token
//   gated  = fused * (1 - p) + (mask_token + 2D sin-cos code) * p  (soft_with_pe)
#pragma once
#include <cstdint>
#include <map>
#include <utility>
#include <vector>

#include "engine/engine.h"
#include "engine/recorder.h"
#include "model/spar_config.h"
#include "model/weight_set.h"

namespace spar {

class TokenGating {
 public:
  TokenGating(Engine& engine, WeightSet& weights, const SparConfig& config);

  // img, ray: [V, n, D] tokens of all views; inputs: the input positions; fused: [K*n, D] out.
  void fuse(Recorder& rec, const Tensor& img, const Tensor& ray, const std::vector<int64_t>& inputs,
            const Tensor& fused);
  // prob: [K, 1, H, W] P(dynamic) of the inputs; dynPatch: [K, 1, gh, gw] out (the pooled p,
  // one value per 16x16 pixels: the photometric tokens' patches, and the semantic tokens' fixed
  // 16x16 pooling); gated: [K*gh*gw, D] out. With masking mode "none" gated is a copy of fused.
  void gate(Recorder& rec, const Tensor& fused, const Tensor& prob, const Tensor& dynPatch, const Tensor& gated);

 private:
  Engine& engine_;
  const SparConfig& config_;
  const Tensor& codeAndMask(Recorder& rec, int64_t gh, int64_t gw);
  Tensor lnW_, w1_, b1_, w2_, b2_, viewType0_, mask_;
  std::map<std::pair<int64_t, int64_t>, Tensor> codes_;  // 2D sin-cos code and mask token per token grid
  Tensor concat_, hidden_;  // scratch [K*n, 2D] and [K*n, D], kept for the next call of that size
};

}  // namespace spar
