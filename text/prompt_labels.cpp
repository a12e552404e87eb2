#include "text/prompt_labels.h"

#include "spar/error.h"
#include "text/bpe_tokenizer.h"

namespace spar {

TokenizedPrompts tokenizePrompts(const PackedModel& model, const std::vector<std::string>& prompts) {
  if (!model.has(BpeTokenizer::kPackedName))
    throw Error(model.path() + ": no CLIP text encoder tokenizer (pack the model with spar-convert --bpe)");
  const BpeTokenizer tokenizer = BpeTokenizer::fromModel(model);
  TokenizedPrompts out;
  for (const std::string& p : prompts) {
    const size_t tokens = tokenizer.encode(p).size() + 2;  // with start and end
    if (tokens > size_t(BpeTokenizer::kContextLength))
      out.warnings.push_back("prompt '" + (p.size() > 40 ? p.substr(0, 40) + "..." : p) + "' is " +
                             std::to_string(tokens) + " tokens: CLIP reads the first " +
                             std::to_string(BpeTokenizer::kContextLength));
  }
  out.ids = tokenizer.tokenize(prompts);
  return out;
}

}  // namespace spar
