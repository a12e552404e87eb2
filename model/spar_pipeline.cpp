// SPAR's pipeline (model/spar_pipeline.h): the request's stage list, run phase by phase; each
// stage recorded and run as one submission so that its GPU time (timestamps) and wall time are
// known (or submitting its own work: SAM2.1, a render call, the label phases).
#include "model/spar_pipeline.h"

#include <algorithm>
#include <chrono>
#include <cstdio>

#include "engine/memory.h"
#include "engine/ops/copy2d.h"
#include "engine/ops/im2col.h"
#include "engine/recorder.h"
#include "model/camera_checks.h"
#include "model/nonfinite_watch.h"
#include "model/stage_models.h"
#include "model/stages/stage_list.h"
#include "model/transformer_block.h"
#include "spar/error.h"

namespace spar {
namespace {

using Clock = std::chrono::steady_clock;
double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

}  // namespace

SparPipeline::SparPipeline(Engine& engine, const PackedModel& model, const SparPipelineOptions& options)
    : engine_(engine),
      model_(model),
      options_(options),
      config_(SparConfig::fromJson(model.config(), model.path())),
      weights_(engine, model, options.weightType),
      models_(std::make_unique<StageModels>(engine, model, config_, weights_)),
      ws_(std::make_unique<TransformerWorkspace>()),
      watch_(std::make_unique<NonFiniteWatch>(engine)) {}

SparPipeline::~SparPipeline() = default;

void SparPipeline::keep(const std::string& name, const Tensor& t) {
  if (options_.keepIntermediates && t.defined()) kept_[name] = t;
}

const Tensor& SparPipeline::intermediate(const std::string& name) const {
  auto it = kept_.find(name);
  if (it == kept_.end()) throw Error("no intermediate '" + name + "' (keepIntermediates off, or the stage did not run)");
  return it->second;
}

std::vector<std::string> SparPipeline::intermediateNames() const {
  std::vector<std::string> out;
  for (const auto& [k, v] : kept_) out.push_back(k);
  return out;
}

void SparPipeline::recordStageTime(const std::string& name, double gpuMs, double wallMs, double buildMs,
                                   const StageCounts& counts) {
  const uint64_t inUse = engine_.memory().bytesInUse(), peak = engine_.memory().peakBytes();
  auto it = std::find_if(stageTimes_.begin(), stageTimes_.end(), [&](const StageTime& s) { return s.name == name; });
  if (it == stageTimes_.end()) {
    stageTimes_.push_back({name, 0, 0, 0, inUse, peak});
    it = stageTimes_.end() - 1;
  }
  it->gpuMs += gpuMs;
  it->wallMs += wallMs;
  it->buildMs += buildMs;
  it->deviceBytesAfter = std::max(it->deviceBytesAfter, inUse);
  it->devicePeakBytes = std::max(it->devicePeakBytes, peak);
  it->dispatches += counts.dispatches;
  it->barriers += counts.barriers;
  it->submits += counts.submits;
  it->transformerBlocks += counts.transformerBlocks;
  it->blockDispatches = std::max(it->blockDispatches, counts.blockDispatches);
}

// A submission's times per stage. GPU and build times come from the timestamps of each stage's
// dispatches; the submission's wall time (what the host waited) is shared out by them, added to
// the time each stage took to record. Counts: the recorder's per stage.
void SparPipeline::addBatchTimes(const Recorder& rec, const std::map<std::string, double>& recordMs, double runMs) {
  std::map<std::string, double> gpu, build;
  // EngineOptions::profileDispatches (SPAR_PROFILE=1): every dispatch's GPU time on stderr
  // (what a stage spends its time on), and the driver's build before it where there was one.
  const bool profile = engine_.options().profileDispatches;
  for (const DispatchTiming& t : rec.timings()) {
    gpu[t.stage] += t.ms;
    build[t.stage] += t.buildMs;
    if (profile && t.buildMs > 0)
      std::fprintf(stderr, "profile %-16s %-28s %10.3f ms (driver build before it: %.1f ms)\n", t.stage.c_str(),
                   t.label.c_str(), t.ms, t.buildMs);
    else if (profile)
      std::fprintf(stderr, "profile %-16s %-28s %10.3f ms\n", t.stage.c_str(), t.label.c_str(), t.ms);
  }
  const std::vector<std::string>& stages = rec.lastRunStages();
  double busy = 0;
  for (const std::string& s : stages) busy += gpu[s] + build[s];
  for (const std::string& s : stages) {
    const double share = busy > 0 ? (gpu[s] + build[s]) / busy : 1.0 / double(stages.size());
    const auto recorded = recordMs.find(s);
    recordStageTime(s, gpu[s], (recorded == recordMs.end() ? 0.0 : recorded->second) + share * runMs, build[s],
                    rec.lastRunCounts().at(s));
  }
}

void SparPipeline::addStageTimes(const Recorder& rec, double wallMs) { addBatchTimes(rec, {{rec.stage(), 0.0}}, wallMs); }

void SparPipeline::validate(const SparRequest& request) const { validateRequest(config_, model_, request); }

RequestShape SparPipeline::shapeOf(const SparRequest& request, int64_t renderChunk, int64_t prompts) const {
  RequestShape q;
  q.views = request.plan.views;
  q.inputs = int64_t(request.plan.inputs.size());
  q.targets = int64_t(request.plan.targets.size());
  q.renderChunk = renderChunk;
  q.height = request.height ? request.height : config_.imageHeight;
  q.width = request.width ? request.width : config_.imageWidth;
  q.assumeStatic = request.assumeStatic;
  q.semantic = request.semanticFeatures;
  q.labels = prompts > 0;
  q.prompts = prompts;
  q.refine = request.refine || request.maskSource == MaskSource::Refined;
  q.targetMotion = request.targetMotion;
  q.lsegGiven = !request.lsegFeatures.empty();
  q.matrixType = options_.weightType;
  return q;
}

MemoryNeed SparPipeline::memoryNeed(const SparRequest& request, int64_t renderChunk, int64_t prompts) {
  RequestShape q = shapeOf(request, renderChunk, prompts);
  q.staging = !engine_.caps().hostVisibleDeviceLocal;
  q.im2colScratchBytes = ops::im2colScratchBytes(engine_);
  engine_.plan();  // a GPU measures its kernel choice now (once), not inside the request
  q.peakBefore = engine_.memory().peakBytes();
  return estimateMemory(model_, config_, q);
}

// Every stage of the phase that records on `rec` goes into one submission: run when a stage that
// submits its own work comes (it reads what the others computed) and at the phase's end, so
// that a phase waits on the host once.
void SparPipeline::runStages(const StageList& list, StagePhase phase, Recorder* rec, PromptWork* work) {
  std::map<std::string, double> recordMs;  // per stage of the pending submission
  const auto submit = [&]() {
    if (!rec || recordMs.empty()) return;
    const auto t0 = Clock::now();
    rec->run();
    addBatchTimes(*rec, recordMs, msSince(t0));
    recordMs.clear();
  };
  for (const auto& stage : list) {
    if (stage->phase() != phase) continue;
    StageRun run{.engine = engine_,
                 .recorder = rec,
                 .request = request_,
                 .config = config_,
                 .models = *models_,
                 .ws = *ws_,
                 .watch = *watch_,
                 .keepIntermediates = options_.keepIntermediates,
                 .profile = options_.profile,
                 .tensors = tensors_,
                 .encoded = encodedOut_,
                 .keep = [this](const std::string& name, const Tensor& t) { keep(name, t); },
                 .submitted = [this](const Recorder& r, double wallMs) { addStageTimes(r, wallMs); },
                 .recordTime = [this](const std::string& name, double gpu, double wall, double build,
                                      const StageCounts& counts) { recordStageTime(name, gpu, wall, build, counts); },
                 .prompts = work};
    if (stage->ownsSubmissions()) {
      submit();
      stage->record(run);
      continue;
    }
    const auto t0 = Clock::now();
    rec->setStage(stage->name());
    stage->record(run);
    recordMs[stage->name()] += msSince(t0);
  }
  submit();
}

const SparEncoded& SparPipeline::encode(const SparRequest& request) {
  validate(request);
  request_ = request;
  request_.height = request.height ? request.height : config_.imageHeight;
  request_.width = request.width ? request.width : config_.imageWidth;
  encodedOut_ = SparEncoded{};
  encoded_ = false;
  tensors_.clear();
  stages_ = pipelineStages({model_, config_, shapeOf(request_, 0, 0)});
  models_->tokenizer();  // the first stage's weights reach the device first, before any activation
  Recorder rec(engine_, options_.profile);
  runStages(stages_, StagePhase::Encode, &rec);
  // A NaN or infinity anywhere above is an error naming where it started, not null cameras.
  watch_->check("encoding the views");

  // ---- host copies; the device keeps what render calls read
  encodedOut_.c2w = engine_.download(tensors_.at("c2w"));
  encodedOut_.fxfycxcy = engine_.download(tensors_.at("fxfycxcy"));
  for (const auto& [name, out] : {std::pair{"cv_drp_input.prob", &encodedOut_.motionInput},
                                  std::pair{"cv_drp_target.prob", &encodedOut_.motionTarget}})
    if (tensors_.count(name)) *out = engine_.download(tensors_.at(name));
  encodedOut_.canonicalIndex = config_.canonicalIndex(request_.plan.views);
  std::erase_if(tensors_, [](const auto& t) {
    return t.first != "c2w" && t.first != "fxfycxcy" && t.first != "scene_encoder_out";
  });
  encoded_ = true;
  return encodedOut_;
}

std::vector<float> SparPipeline::renderRays(Recorder& rec, const Tensor& c2w, const Tensor& fxfycxcy) {
  features_ = Tensor();  // the previous call's features are replaced
  tensors_.erase("semantic_features");
  tensors_["render_c2w"] = c2w;
  tensors_["render_fxfycxcy"] = fxfycxcy;
  watch_->reset();
  runStages(stages_, StagePhase::Render, &rec);
  watch_->check("rendering");
  keep("render_c2w", c2w);
  keep("render_fxfycxcy", fxfycxcy);
  const Tensor rgb = tensors_.at("rgb");
  features_ = tensors_.at("semantic_features");
  for (const char* name : {"render_c2w", "render_fxfycxcy", "rgb"}) tensors_.erase(name);
  return engine_.download(rgb);
}

std::vector<float> SparPipeline::renderTargets() {
  if (!encoded_) throw Error("render before encode");
  const auto& targets = request_.plan.targets;
  const int64_t t = int64_t(targets.size());
  if (t == 0) return {};
  // The targets' estimated cameras, gathered on the device in the render call's submission.
  const Tensor c2w = engine_.tensor({t, 4, 4}), k = engine_.tensor({t, 4});
  Recorder rec(engine_, options_.profile);
  rec.setStage("render_rays");
  const Tensor& all = tensors_.at("c2w");
  for (int64_t j = 0; j < t; ++j) {
    copy2d(rec, all.reshape({request_.plan.views, 16}).view(targets[j] * 16, {1, 16}), 16, 0,
           c2w.view(j * 16, {1, 16}), 16, 0, 1, 16);
    copy2d(rec, tensors_.at("fxfycxcy").view(targets[j] * 4, {1, 4}), 4, 0, k.view(j * 4, {1, 4}), 4, 0, 1, 4);
  }
  return renderRays(rec, c2w, k);
}

std::vector<float> SparPipeline::render(const RenderCameras& cameras) {
  if (!encoded_) throw Error("render before encode");
  const int64_t r = int64_t(cameras.size());
  if (r == 0) return {};
  if (cameras.fxfycxcy.size() != cameras.c2w.size()) throw Error("render cameras: as many intrinsics as poses needed");
  for (int64_t j = 0; j < r; ++j)
    if (const std::string p = renderCameraProblem(cameras.c2w[j], cameras.fxfycxcy[j]); !p.empty())
      throw Error("render camera " + std::to_string(j) + ": " + p);
  std::vector<float> c2w, k;
  for (int64_t j = 0; j < r; ++j) {
    c2w.insert(c2w.end(), cameras.c2w[j].begin(), cameras.c2w[j].end());
    k.insert(k.end(), cameras.fxfycxcy[j].begin(), cameras.fxfycxcy[j].end());
  }
  const Tensor tc = engine_.fromFloats({r, 4, 4}, c2w), tk = engine_.fromFloats({r, 4}, k);
  Recorder rec(engine_, options_.profile);
  return renderRays(rec, tc, tk);
}

// The label phases' stages, as the list of a request with prompts has them.
StageList SparPipeline::labelStages() const {
  RequestShape shape = shapeOf(request_, 0, 1);
  return pipelineStages({model_, config_, shape});
}

void SparPipeline::encodePrompts(const std::vector<int32_t>& ids, int64_t count) {
  PromptWork work{.ids = &ids, .count = count, .text = &text_};
  runStages(labelStages(), StagePhase::Prompts, nullptr, &work);
}

std::vector<std::vector<int32_t>> SparPipeline::labelMaps(std::vector<float>* scores) {
  if (!features_.defined()) throw Error("label maps need a render call with semantic features");
  if (!text_.text.defined()) throw Error("label maps need encoded prompts");
  LabelMapsOut out;
  PromptWork work{.text = &text_, .scores = scores, .maps = &out};
  runStages(labelStages(), StagePhase::Labels, nullptr, &work);
  return std::move(out.maps);
}

uint64_t SparPipeline::weightBytesLoaded() const {
  return weights_.bytesLoaded() + (text_.weights ? text_.weights->bytesLoaded() : 0);
}

}  // namespace spar
