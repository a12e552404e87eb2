// Tokenizers of SPAR's views (reference: reference/spar_reference/spar.py SPAR.forward, "image
// tokens with spatial-temporal codes", camera_tokens, and the ray tokenizers):
//
//   image tokens   image_tokenizer(patchify(2*img - 1)) + pe_embedder(concat(2D code, view code))
//   camera tokens  cam_code + temporal_pe_embedder(1D code of the view index)
//   ray tokens     <tokenizer>(patchify(rays)), tokenizer = target_pose_tokenizer (all views, for
//                  CV-DRP and mlp_fuse) or target_pose_tokenizer2 (the decoder's RGB queries)
//
// Patchify is (ph pw c), channel fastest; every Linear has no bias; the embedders are
// Linear -> SiLU -> Linear with biases. The sin-cos codes are host tables (model/sincos_codes.h)
// uploaded once per size.
#pragma once
#include <cstdint>
#include <map>
#include <string>
#include <utility>

#include "engine/engine.h"
#include "engine/recorder.h"
#include "model/spar_config.h"
#include "model/weight_set.h"

namespace spar {

class ViewTokenizer {
 public:
  ViewTokenizer(Engine& engine, WeightSet& weights, const SparConfig& config);

  // images [V, 3, H, W] in [0, 1] -> raw [V, n, D] (before the codes), tokens [V, n, D].
  // code (optional, for tests): [V, n, D] receives the sin-cos code fed to pe_embedder.
  void imageTokens(Recorder& rec, const Tensor& images, const Tensor& raw, const Tensor& tokens,
                   const Tensor& code = Tensor());
  // [V, D] camera tokens of a sequence of V views.
  void cameraTokens(Recorder& rec, int64_t views, const Tensor& out);
  // rays [V, 6, H, W] -> [V, n, D] through tokenizer `name` ("target_pose_tokenizer", ...).
  void rayTokens(Recorder& rec, const std::string& name, const Tensor& rays, const Tensor& out);

 private:
  const Tensor& imageCode(int64_t views, int64_t gh, int64_t gw);
  const Tensor& cameraCode(int64_t views);

  Engine& engine_;
  WeightSet& weights_;
  const SparConfig& config_;
  std::map<std::pair<int64_t, std::pair<int64_t, int64_t>>, Tensor> imageCodes_;
  std::map<int64_t, Tensor> cameraCodes_;
};

}  // namespace spar
