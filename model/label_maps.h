// Open-vocabulary label maps on the engine, as LSeg / SPAR compute them
// (reference/spar_reference/clip_text.py label_logits, cli.py compute_labels):
//
//   image features [R, C, h, w] and text embeddings [P, C], both L2-normalized over C
//   logits [R, P, h, w] = scale * <image, text>      (scale = 1 / 0.07, LSeg's fixed value)
//   maps [R, 2h, 2w] = argmax over the prompts of the logits upsampled x2 (bilinear,
//                      align_corners=True: LSeg's scratch.output_conv), the first maximum
//
// The label map is at the image's size (h, w are half of it), in the official order: the
// scores are enlarged before the argmax (resizeBilinearArgmax, which never stores them), not
// the half-resolution map afterwards (they differ wherever labels change within two pixels).
// The dot products run as a 1x1 convolution whose kernel is the normalized text [P, C, 1, 1].
// Vectors of norm 0 normalize to 0 here (F.normalize's eps) where the reference divides by 0
// and gets NaN; SPAR's features and CLIP's embeddings are never 0.
#pragma once
#include "engine/engine.h"
#include "engine/recorder.h"

namespace spar {

// LSeg's logit scale: exp(log(1 / 0.07)), a constant, not a weight.
constexpr double kLsegLogitScale = 1.0 / 0.07;

// features: f32 [R, C, h, w]; text: f32 [P, C]; logits: f32 [R, P, h, w], written.
void labelLogits(Recorder& rec, const Tensor& features, const Tensor& text, const Tensor& logits,
                 float logitScale = static_cast<float>(kLsegLogitScale));

// maps: I32 [R, 2h, 2w], written. logits: f32 [R, P, h, w] to keep the per-label score maps
// (before the upsampling: the official logits), or undefined (then a scratch tensor holds them).
void labelMaps(Recorder& rec, const Tensor& features, const Tensor& text, const Tensor& maps,
               const Tensor& logits = Tensor(), float logitScale = static_cast<float>(kLsegLogitScale));

}  // namespace spar
