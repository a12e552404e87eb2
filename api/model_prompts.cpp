// spar::Model::promptWarnings (include/spar/model.h): the one Model call that tokenizes, apart
// so that a program that never does links no tokenizer.
#include "api/api_impl.h"
#include "text/prompt_labels.h"

namespace spar {

std::vector<std::string> Model::promptWarnings(const std::vector<std::string>& prompts) const {
  return tokenizePrompts(impl_->file, prompts).warnings;
}

}  // namespace spar
