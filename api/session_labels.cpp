// spar::Session's label maps (include/spar/session.h): the prompts tokenized and through CLIP's
// text encoder once, then each render call's features to label maps, with their stage times.
#include "api/session_impl.h"
#include "spar/error.h"
#include "text/prompt_labels.h"

namespace spar {

void Session::preparePrompts(const std::vector<std::string>& prompts, std::vector<std::string>* warnings) {
  Impl& s = *impl_;
  if (!s.pipeline.config().semanticDecoding())
    throw Error("label maps need a model with the semantic branch; " + s.model.path() + " has none");
  if (prompts.empty()) throw Error("label maps need at least one prompt");
  if (prompts != s.prompts || !s.pipeline.promptsEncoded()) {
    const TokenizedPrompts tokenized = tokenizePrompts(s.model, prompts);
    s.pipeline.encodePrompts(tokenized.ids, int64_t(prompts.size()));
    s.prompts = prompts;
    s.promptWarnings = tokenized.warnings;
  }
  if (warnings) *warnings = s.promptWarnings;
}

std::vector<std::vector<int32_t>> Session::labelMaps(const std::vector<std::string>& prompts,
                                                     std::vector<std::string>* warnings, std::vector<float>* scores) {
  Impl& s = *impl_;
  if (!s.pipeline.config().semanticDecoding())
    throw Error("label maps need a model with the semantic branch; " + s.model.path() + " has none");
  if (!s.features || !s.rendered)
    throw Error("label maps need a render call after an encode whose request asked for semanticFeatures");
  preparePrompts(prompts, warnings);
  return s.pipeline.labelMaps(scores);
}

}  // namespace spar
