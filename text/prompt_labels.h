// Open-vocabulary labels from text prompts: the prompts tokenized (CLIP's BPE tokenizer packed in
// the model), then through CLIP's text encoder and into label maps on the device
// (model/prompt_label_maps.h, included here for the callers that do both).
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "model/packed_model.h"
#include "model/prompt_label_maps.h"

namespace spar {

// CLIP token ids [P, 77] of the prompts, and a warning for each prompt longer than CLIP reads;
// throws spar::Error when the model has no tokenizer.
struct TokenizedPrompts {
  std::vector<int32_t> ids;
  std::vector<std::string> warnings;
};
TokenizedPrompts tokenizePrompts(const PackedModel& model, const std::vector<std::string>& prompts);

}  // namespace spar
