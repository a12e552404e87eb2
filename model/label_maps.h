// Open-vocabulary label maps on the engine, as LSeg / SPAR compute them
// (reference/spar_reference/clip_text.py label_logits, cli.py compute_labels):
//
//   image features [R, C, h, w] and text embeddings [P, C], both L2-normalized over C
//   logits [R, P, h, w] = scale * <image, text>      (scale = 1 / 0.07, LSeg's fixed value)
//   maps [R, h, w] = argmax over the prompts          (int32, the first maximum)
//
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

// maps: I32 [R, h, w], written. logits: f32 [R, P, h, w] to keep the per-label score maps, or
// undefined (then a scratch tensor holds them).
void labelMaps(Recorder& rec, const Tensor& features, const Tensor& text, const Tensor& maps,
               const Tensor& logits = Tensor(), float logitScale = static_cast<float>(kLsegLogitScale));

}  // namespace spar
