// SAM2.1's image encoder as the refinement path runs it (official SAM2ImagePredictor.set_image:
// Hiera trunk, FPN neck with scalp 1, conv_s0 / conv_s1 of the mask decoder, no_mem_embed;
// reference reference/spar_reference/sam2.py image_encoder), on the engine:
//
//   view of images [V, 3, H, W] in [0, 1] -> sam2Preprocess -> [3, 1024, 1024]
//   patch embedding (Conv 7x7 stride 4 pad 3) -> tokens [256 * 256, C0] + position table
//   the Hiera blocks (model/sam2_hiera_block.h); the outputs of the 4 stages' last blocks
//   neck: 1x1 lateral convs (as GEMMs on the channel-last tokens), deepest first; level 2 =
//   lateral + nearest x2 of level 3; levels 0, 1 lateral only
//
// Features, channel-last tokens: imageEmbed [64 * 64, d] = L2 + no_mem_embed, featS0
// [256 * 256, d / 8] = conv_s0(L0), featS1 [128 * 128, d / 4] = conv_s1(L1). Weights by
// official key under `prefix` ("sam2." in a packed file).
#pragma once
#include <functional>
#include <string>
#include <vector>

#include "engine/engine.h"
#include "engine/recorder.h"
#include "model/sam2_config.h"
#include "model/transformer_block.h"

namespace spar {

struct Sam2ImageFeatures {
  Tensor imageEmbed, featS0, featS1;
  std::vector<Tensor> stages;  // the trunk's 4 stage maps [H, W, C] (checked by the tests)
};

class Sam2ImageEncoder {
 public:
  // Looks up the weights and computes the position table (input-independent) once.
  Sam2ImageEncoder(Engine& engine, const Sam2Config& config, WeightLookup weights, std::string prefix = "sam2.");

  // With `flush`: called after each Hiera block (the refiner's submission: run, timings), so
  // a block's intermediates are freed before the next one's are allocated; the device then
  // holds one block's maps at a time instead of all of them (hiera_l, 2 views: a 10 GB peak
  // before). Without: everything is recorded into `rec` for one submission.
  Sam2ImageFeatures encode(Recorder& rec, const Tensor& images, int64_t view,
                           const std::function<void(Recorder&)>& flush = {}) const;
  const Tensor& positionTable() const { return positionTable_; }

 private:
  Tensor weight(const std::string& name) const;
  Engine& engine_;
  Sam2Config config_;
  WeightLookup weights_;
  std::string prefix_;
  Tensor positionTable_;  // [256 * 256, C0]
};

}  // namespace spar
