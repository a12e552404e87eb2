// spar::Session (include/spar/session.h): the model's pipeline on the context's engine.
#include "spar/session.h"

#include "api/api_impl.h"
#include "model/spar_pipeline.h"

namespace spar {

struct Session::Impl {
  Engine& engine;
  SparPipeline pipeline;
  bool features = false;  // the last request asked for semantic features
  Impl(Engine& e, const PackedModel& model, const SparPipelineOptions& o) : engine(e), pipeline(e, model, o) {}
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
  return impl_->pipeline.encode(request);
}

std::vector<float> Session::renderTargets() { return impl_->pipeline.renderTargets(); }
std::vector<float> Session::render(const RenderCameras& cameras) { return impl_->pipeline.render(cameras); }

std::vector<float> Session::features() {
  if (!impl_->features) return {};
  const Tensor& f = impl_->pipeline.renderedFeatures();
  return f.defined() ? impl_->engine.download(f) : std::vector<float>{};
}

const std::vector<StageTime>& Session::stageTimes() const { return impl_->pipeline.stageTimes(); }

}  // namespace spar
