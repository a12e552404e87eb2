// Open-vocabulary label maps from prompts on the device: the prompts' CLIP text embeddings once
// (model/clip_text.*), then the label maps of any number of rendered views' semantic features
// (model/label_maps.*). Used by spar::Session::labelMaps (the public API), `spar render
// --labels`, `spar eval` and `spar selftest`; text/prompt_labels.h turns prompts into the token
// ids these take (the tokenizer, which needs ICU, stays out of programs that do not tokenize).
#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "engine/engine.h"
#include "engine/recorder.h"
#include "model/packed_model.h"
#include "model/spar_config.h"
#include "model/weight_set.h"

namespace spar {

// The prompts' text embeddings [P, E] on the device. The text encoder's weights live in their
// own WeightSet, loaded only when labels are asked for.
struct PromptEmbeddings {
  std::unique_ptr<WeightSet> weights;
  Tensor text;
  int64_t prompts = 0;
  double gpuMs = 0, wallMs = 0, buildMs = 0;
  StageCounts counts;  // its dispatches, barriers, submission, transformer blocks
};
PromptEmbeddings encodePrompts(Engine& engine, const PackedModel& model, const SparConfig& config, DType weightType,
                               const std::vector<int32_t>& ids, int64_t prompts);

// Label maps of features [R, C, h, w] at the image's size (model/label_maps.h: the scores x2
// bilinear, then the argmax over the prompts, first maximum): one [2h * 2w] map per view; with
// scores also the per-label score maps [R, P, h, w] (the official logits, before the
// upsampling) appended to *scores.
struct LabelMapsOut {
  std::vector<std::vector<int32_t>> maps;
  double gpuMs = 0, buildMs = 0;
  StageCounts counts;
};
LabelMapsOut computeLabelMaps(Engine& engine, const Tensor& features, const PromptEmbeddings& prompts,
                              std::vector<float>* scores = nullptr);

}  // namespace spar
