// SPAR's pipeline on the engine, stage by stage as the paper's Figure 2 draws it (reference:
// reference/spar_reference/spar.py SPAR.forward and SPAR.render). The stages are objects
// (model/pipeline_stage.h) in a list that holds only what a request needs
// (model/stages/stage_list.h): no CV-DRP or DINOv3 with assumeStatic, no SAM2.1 unless refining,
// no semantic stages on a model without the branch, no text encoder without prompts.
//
//   images -> image tokens, camera tokens -> pose estimator -> cameras -> rays, ray tokens
//          -> DINOv3 -> CV-DRP motion probability -> (asked for) SAM2.1 refinement
//          -> mlp_fuse + gating -> (semantic models) LSeg -> semantic tokens, gated
//          -> scene encoder -> scene tokens
//   render: ray queries + scene tokens -> decoder -> RGB head (and semantic head)
//   labels: prompts -> CLIP text encoder; rendered features -> label maps
//
// Work happens in phases so that rendering cameras may depend on the estimated ones (a path
// through the input cameras): encode() runs the encode stages and leaves the cameras and motion
// maps on the host; render*() decodes any number of views from the scene tokens kept on the
// device; encodePrompts() and labelMaps() make label maps of the last render call.
#pragma once
#include <array>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "engine/engine.h"
#include "model/memory_estimate.h"
#include "model/packed_model.h"
#include "model/pipeline_stage.h"
#include "model/prompt_label_maps.h"
#include "model/request_checks.h"
#include "model/spar_config.h"
#include "model/weight_set.h"
#include "spar/request.h"

namespace spar {

class NonFiniteWatch;  // model/nonfinite_watch.h
class TransformerWorkspace;

// The request types are public (include/spar/request.h); the pipeline's own names for them:
using SparRequest = Request;
using SparEncoded = Encoded;

struct SparPipelineOptions {
  bool profile = true;            // per-dispatch timestamps -> stageTimes()
  // Keep every stage's output tensor under its golden name (reference/spar_reference/
  // goldens.py: "img_tokens", "pose_encoder_out", "c2w", ..., "rgb") for tests; costs memory.
  bool keepIntermediates = false;
  // Weight matrices on the device: F32 as the file stores them (F16 in a `spar-convert --fp16`
  // pack); F16 as fp16 even from an F32 file, with the values that pack would hold. Norms,
  // biases, learned tokens and codes stay F32; activations are F32 either way.
  DType weightType = DType::F32;
};

class SparPipeline {
 public:
  // Parses the configuration; weights are uploaded lazily as stages first need them.
  SparPipeline(Engine& engine, const PackedModel& model, const SparPipelineOptions& options = {});
  ~SparPipeline();
  SparPipeline(const SparPipeline&) = delete;
  SparPipeline& operator=(const SparPipeline&) = delete;

  const SparConfig& config() const { return config_; }

  // Throws spar::Error (one line) for a request this model cannot run (model/request_checks.h).
  void validate(const SparRequest& request) const;
  // What the stage list and the memory estimate take of `request`, when render calls render
  // `renderChunk` views and label maps are asked for `prompts` prompts.
  RequestShape shapeOf(const SparRequest& request, int64_t renderChunk, int64_t prompts) const;
  // The device memory `request` needs (model/memory_estimate.h), before any work. On a GPU the
  // first call measures the kernel choice (the estimate follows what will run).
  MemoryNeed memoryNeed(const SparRequest& request, int64_t renderChunk, int64_t prompts);

  // Phase 1. Throws spar::Error (one line) for bad requests (validate()).
  const SparEncoded& encode(const SparRequest& request);
  // Phase 2 (after encode): the plan's targets with their estimated cameras, or explicit
  // cameras. Returns RGB [R, 3, H, W] in [0, 1].
  std::vector<float> renderTargets();
  std::vector<float> render(const RenderCameras& cameras);
  // The semantic features [R, C, H/2, W/2] of the last render*() call on the device (undefined
  // unless the request asked for semanticFeatures); valid until the next render*() call.
  const Tensor& renderedFeatures() const { return features_; }

  // The prompts' text embeddings (CLIP token ids [count, 77]), kept for labelMaps(); the text
  // encoder's weights are uploaded now, once.
  void encodePrompts(const std::vector<int32_t>& ids, int64_t count);
  bool promptsEncoded() const { return text_.text.defined(); }
  // Label maps of the last render call's features against the encoded prompts
  // (model/prompt_label_maps.h computeLabelMaps).
  std::vector<std::vector<int32_t>> labelMaps(std::vector<float>* scores = nullptr);

  // Stages that ran since construction (in order, accumulated by name).
  const std::vector<StageTime>& stageTimes() const { return stageTimes_; }
  // Adds a stage's times and command counts to stageTimes() (by name), with the device memory now.
  void recordStageTime(const std::string& name, double gpuMs, double wallMs, double buildMs,
                       const StageCounts& counts = {});
  // Weights uploaded so far, the text encoder's included.
  uint64_t weightBytesLoaded() const;
  const WeightSet& weights() const { return weights_; }

  // With keepIntermediates: the device tensor stored under a golden name (throws if absent).
  const Tensor& intermediate(const std::string& name) const;
  std::vector<std::string> intermediateNames() const;

 private:
  // Runs the stages of `phase` in `list`: those that record on `rec` in one submission (split
  // only where a stage submits its own work), with their times and counts per stage.
  void runStages(const StageList& list, StagePhase phase, Recorder* rec, PromptWork* work = nullptr);
  void addBatchTimes(const Recorder& rec, const std::map<std::string, double>& recordMs, double runMs);
  StageList labelStages() const;
  void keep(const std::string& name, const Tensor& t);
  void addStageTimes(const Recorder& rec, double wallMs);
  // A render call on `rec` (which may hold the cameras' gathering): one submission.
  std::vector<float> renderRays(Recorder& rec, const Tensor& c2w, const Tensor& fxfycxcy);

  Engine& engine_;
  const PackedModel& model_;
  SparPipelineOptions options_;
  SparConfig config_;
  WeightSet weights_;
  std::unique_ptr<StageModels> models_;
  std::unique_ptr<TransformerWorkspace> ws_;
  std::unique_ptr<NonFiniteWatch> watch_;  // where a NaN / infinity first appeared
  StageList stages_;                        // the last encoded request's
  // Between stages and calls: what render calls read (the cameras, the scene tokens) after an
  // encode, and a render call's inputs and outputs.
  std::map<std::string, Tensor> tensors_;
  bool encoded_ = false;
  SparEncoded encodedOut_;
  SparRequest request_;
  std::map<std::string, Tensor> kept_;
  Tensor features_;
  PromptEmbeddings text_;
  std::vector<StageTime> stageTimes_;
};

}  // namespace spar
