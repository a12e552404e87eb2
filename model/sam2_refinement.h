// SPAR's SAM2.1 refinement of motion masks (official SPAR _sam2_refine_masks; reference
// reference/spar_reference/sam2.py refine_masks), on the engine, per view:
//
//   binary = P(dynamic) > 0.5; fewer than 10 dynamic pixels, or more than H*W - 10: not
//   refined (the output is binary; no encoder runs)
//   else: image encoder (model/sam2_image_encoder.h), mask decoder with binary as the prompt
//   (model/sam2_mask_decoder.h); the highest-IoU mask's 256x256 logits resized bilinearly to
//   H x W (align_corners=False) and thresholded at 0: a hard 0/1 mask
//
// The dynamic pixels of every view are counted on the device and read back as V integers,
// the one readback that decides which views run the encoder.
#pragma once
#include <array>
#include <functional>
#include <string>
#include <vector>

#include "engine/engine.h"
#include "model/sam2_image_encoder.h"
#include "model/sam2_mask_decoder.h"

namespace spar {

class WeightSet;

// SAM2's weights from a model's weight set: convolution kernels (rank 4) as f32, which the
// engine's convolutions read (an fp16 set gives them fp16-rounded), everything else as the set
// gives it (matrices fp16 under fp16 weights).
WeightLookup sam2Weights(WeightSet& weights);

struct Sam2ViewRefinement {
  bool skipped = false;
  int64_t dynamicPixels = 0;    // P(dynamic) > 0.5
  std::array<float, 3> iou{};   // the multimask outputs' IoU predictions (not skipped)
  int chosen = -1;              // argmax of iou, the first of equal ones (not skipped)
  std::vector<float> logits;    // the chosen mask's 256 x 256 low-resolution logits (not skipped)
};

struct Sam2Refined {
  std::vector<float> masks;              // [V, H, W], 0 or 1
  std::vector<Sam2ViewRefinement> views;
};

class Sam2Refiner {
 public:
  Sam2Refiner(Engine& engine, const Sam2Config& config, const WeightLookup& weights, const std::string& prefix = "sam2.");

  // images [V, 3, H, W] in [0, 1], probs [V, H, W] P(dynamic). `ran`, when given, is called
  // after each submission with its recorder (profiled, stage "sam2_refine"): the caller's
  // stage times.
  Sam2Refined refine(const Tensor& images, const Tensor& probs,
                     const std::function<void(const Recorder&)>& ran = {});

  static constexpr int64_t kSkipMin = 10;  // SPAR: refined only when 10 <= dynamic <= H*W - 10

 private:
  Engine& engine_;
  int64_t maskSide_;  // the decoder's logits and the mask prompt: Sam2Config::maskInputSize()
  Sam2ImageEncoder encoder_;
  Sam2MaskDecoder decoder_;
};

}  // namespace spar
