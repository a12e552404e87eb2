// spar::Session (include/spar/session.h): the model's pipeline on the context's engine.
#include "spar/session.h"

#include "api/api_impl.h"
#include "engine/error.h"
#include "text/prompt_labels.h"
#include "model/spar_pipeline.h"

namespace spar {

struct Session::Impl {
  Engine& engine;
  const PackedModel& model;
  SparPipelineOptions options;
  SparPipeline pipeline;
  bool features = false;  // the last request asked for semantic features
  bool rendered = false;  // a render call since the last encode
  std::vector<std::string> prompts;  // whose embeddings `text` holds
  std::vector<std::string> promptWarnings;
  PromptEmbeddings text;
  Impl(Engine& e, const PackedModel& m, const SparPipelineOptions& o) : engine(e), model(m), options(o), pipeline(e, m, o) {}
};

namespace {

SparPipelineOptions pipelineOptions(const SessionOptions& o) {
  SparPipelineOptions p;
  p.profile = o.profile;
  if (o.fp16Weights) p.weightType = DType::F16;
  return p;
}

}  // namespace

Session::Session(Context& context, const Model& model, const SessionOptions& options)
    : impl_(std::make_unique<Impl>(context.impl().engine, model.impl().file, pipelineOptions(options))) {}
Session::~Session() = default;

const Encoded& Session::encode(const Request& request) {
  impl_->features = request.semanticFeatures && impl_->pipeline.config().semanticDecoding();
  impl_->rendered = false;
  return impl_->pipeline.encode(request);
}

std::vector<float> Session::renderTargets() {
  std::vector<float> rgb = impl_->pipeline.renderTargets();
  impl_->rendered = true;
  return rgb;
}

std::vector<float> Session::render(const RenderCameras& cameras) {
  std::vector<float> rgb = impl_->pipeline.render(cameras);
  impl_->rendered = true;
  return rgb;
}

std::vector<std::vector<int32_t>> Session::labelMaps(const std::vector<std::string>& prompts,
                                                     std::vector<std::string>* warnings) {
  Impl& s = *impl_;
  if (!s.pipeline.config().semanticDecoding())
    throw Error("label maps need a model with the semantic branch; " + s.model.path() + " has none");
  if (!s.features || !s.rendered)
    throw Error("label maps need a render call after an encode whose request asked for semanticFeatures");
  if (prompts.empty()) throw Error("label maps need at least one prompt");
  if (prompts != s.prompts || !s.text.text.defined()) {
    const TokenizedPrompts tokenized = tokenizePrompts(s.model, prompts);
    s.text = encodePrompts(s.engine, s.model, s.pipeline.config(), s.options.weightType, tokenized.ids,
                           int64_t(prompts.size()));
    s.prompts = prompts;
    s.promptWarnings = tokenized.warnings;
  }
  if (warnings) *warnings = s.promptWarnings;
  return computeLabelMaps(s.engine, s.pipeline.renderedFeatures(), s.text).maps;
}

std::vector<float> Session::features() {
  if (!impl_->features) return {};
  const Tensor& f = impl_->pipeline.renderedFeatures();
  return f.defined() ? impl_->engine.download(f) : std::vector<float>{};
}

const std::vector<StageTime>& Session::stageTimes() const { return impl_->pipeline.stageTimes(); }

}  // namespace spar
