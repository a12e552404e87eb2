// spar::Session (include/spar/session.h): the model's pipeline on the context's engine and the
// memory preflight. Label maps: api/session_labels.cpp (apart, so that a program that makes none
// links no tokenizer).
#include "spar/session.h"

#include "api/session_impl.h"
#include "engine/memory.h"
#include "model/memory_estimate.h"
#include "model/spar_pipeline.h"
#include "spar/error.h"

namespace spar {
namespace {

SparPipelineOptions pipelineOptions(const SessionOptions& o) {
  SparPipelineOptions p;
  p.profile = o.profile;
  p.keepIntermediates = o.keepIntermediates;
  p.weightType = WeightSet::matrixType(o.precision);
  return p;
}

std::string mib(uint64_t b) { return std::to_string((b + (1 << 20) - 1) >> 20) + " MiB"; }

std::string viewsText(const ViewPlan& p) {
  return std::to_string(p.views) + " views (" + std::to_string(p.inputs.size()) + " inputs, " +
         std::to_string(p.targets.size()) + " targets)";
}

// Why `request` cannot run on a device with `budget` bytes ("" when its least need fits).
std::string refusalOf(const MemoryNeed& need, uint64_t budget, const std::string& source, const Request& request,
                      const SparConfig& config) {
  if (!budget || need.total() <= budget) return "";
  const int64_t h = request.height ? request.height : config.imageHeight;
  const int64_t w = request.width ? request.width : config.imageWidth;
  return "this request needs at least " + mib(need.total()) + " of device memory (weights " + mib(need.weightBytes) +
         ", activations " + mib(need.activationBytes) + " for " + viewsText(request.plan) + " at " + std::to_string(h) +
         "x" + std::to_string(w) + "), more than the " + mib(budget) + " available (" + source + ")";
}

}  // namespace

Session::Session(Context& context, const Model& model, const SessionOptions& options)
    : impl_(std::make_unique<Impl>(context.impl().engine, model.impl().file, pipelineOptions(options))) {}
Session::~Session() = default;

MemoryEstimate Session::estimateMemory(const Request& request, const RenderUse& use) {
  Impl& s = *impl_;
  const int64_t perCall = use.viewsPerCall >= 0 ? use.viewsPerCall : int64_t(request.plan.targets.size());
  const MemoryNeed need = s.pipeline.memoryNeed(request, perCall, use.labelPrompts);
  // The most input views this device surely takes at this size: the upper bound grows by about
  // the same amount with each one.
  Request more = request;
  ++more.plan.views;
  more.plan.inputs.push_back(request.plan.views);
  const uint64_t perInput = s.pipeline.memoryNeed(more, perCall, use.labelPrompts).upperBytes - need.upperBytes;
  MemoryEstimate e;
  e.minBytes = need.total();
  e.maxBytes = need.upperBytes;
  e.weightBytes = need.weightBytes;
  e.activationBytes = need.activationBytes;
  e.budgetBytes = s.engine.memory().budget();
  e.budgetSource = s.engine.memory().budgetSource();
  const int64_t inputs = int64_t(request.plan.inputs.size());
  e.maxInputViews = e.budgetBytes > e.maxBytes
                        ? inputs + int64_t((e.budgetBytes - e.maxBytes) / std::max<uint64_t>(perInput, 1))
                        : 0;
  e.refusal = refusalOf(need, e.budgetBytes, e.budgetSource, request, s.pipeline.config());
  if (e.refusal.empty() && e.budgetBytes && e.maxBytes > e.budgetBytes)
    e.warning = "this request may need up to " + mib(e.maxBytes) + " of device memory, more than the " +
                mib(e.budgetBytes) + " available (" + e.budgetSource + "): it may run out midway";
  return e;
}

const Encoded& Session::encode(const Request& request) {
  Impl& s = *impl_;
  s.pipeline.validate(request);  // a request that cannot mean anything is refused as such first
  // Refused before any work when even its least need is above the budget (the least need only:
  // estimateMemory's bound and view count are for callers that ask).
  if (const uint64_t budget = s.engine.memory().budget()) {
    const MemoryNeed need = s.pipeline.memoryNeed(request, int64_t(request.plan.targets.size()), 0);
    if (const std::string refusal = refusalOf(need, budget, s.engine.memory().budgetSource(), request,
                                              s.pipeline.config());
        !refusal.empty())
      throw Error(refusal);
  }
  s.features = request.semanticFeatures && s.pipeline.config().semanticDecoding();
  s.rendered = false;
  return s.pipeline.encode(request);
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

std::vector<float> Session::features() {
  if (!impl_->features) return {};
  const Tensor& f = impl_->pipeline.renderedFeatures();
  return f.defined() ? impl_->engine.download(f) : std::vector<float>{};
}

const std::vector<StageTime>& Session::stageTimes() const { return impl_->pipeline.stageTimes(); }

uint64_t Session::weightBytesLoaded() const { return impl_->pipeline.weightBytesLoaded(); }

std::vector<std::string> Session::intermediateNames() const { return impl_->pipeline.intermediateNames(); }

std::vector<float> Session::intermediate(const std::string& name, std::vector<int64_t>* shape) const {
  const Tensor& t = impl_->pipeline.intermediate(name);
  if (shape) *shape = t.shape();
  return impl_->engine.download(t);
}

}  // namespace spar
