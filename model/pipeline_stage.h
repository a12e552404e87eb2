// One stage of SPAR's pipeline (model/spar_pipeline.h runs a list of them; model/stage_list.h
// says which a request runs): its name, the tensors it reads and writes, the weights it loads,
// what it holds in device memory, and record(). The pipeline runs the list; the memory estimate
// (model/memory_estimate.h) adds up the same list, so a stage added to it is estimated as well.
// docs/contributing.md lists what else a new stage touches.
#pragma once
#include <array>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "engine/engine.h"
#include "engine/recorder.h"
#include "model/spar_config.h"
#include "spar/request.h"

namespace spar {

class NonFiniteWatch;
class PackedModel;
class TransformerWorkspace;
class WeightSet;
struct StageModels;  // model/stage_models.h

// What a request asks of the pipeline, as far as which stages run and how large their tensors
// are: made from a request (SparPipeline::shapeOf) or given to the memory estimate.
struct RequestShape {
  int64_t views = 0, inputs = 0, targets = 0;
  int64_t renderChunk = 0;  // views rendered per render call (targets, or a --path chunk)
  int64_t height = 0, width = 0;
  bool assumeStatic = false;
  bool semantic = false;      // semantic features rendered (models with the semantic branch)
  bool labels = false;        // CLIP's text encoder loaded (prompts)
  int64_t prompts = 0;        // how many label prompts (with labels)
  bool refine = false;        // SAM2.1's refinement (a model packed with it): its weights and maps
  bool targetMotion = false;  // the targets' masks too (refined with them)
  bool lsegGiven = false;     // LSeg features came with the request: the LSeg stage does not run
  DType matrixType = DType::F32;
  // The device copies uploads and downloads through staging buffers of their size (no memory
  // both device-local and mappable): the largest such copy is added to the upper bound.
  bool staging = false;
  // Where convolutions run as im2col and a GEMM (the plan's gemmLanesSplitK): the bytes of a
  // recorder's scratch for their patches (ops::im2colScratchBytes), 0 elsewhere.
  uint64_t im2colScratchBytes = 0;
  // What the engine's memory peaked at before the request (the kernel tuner's measurement on
  // a GPU): the upper bound is at least that, as the measured peak never resets.
  uint64_t peakBefore = 0;
};

// What a stage holds on the device, in floats (4 bytes each), for the memory estimate. Each term
// follows the code that allocates it (named beside it in the stage's file).
struct StageMemory {
  int64_t kept = 0;         // lower bound: its tensors alive through an encode and one render call
  int64_t atEncodeEnd = 0;  // upper bound: its tensors alive when the encode ends
  int64_t transient = 0;    // upper bound: what it holds only until the encode's submission has run
  int64_t own = 0;          // upper bound: buffers, tables and derived weights kept for the request
  int64_t forRenders = 0;   // kept from the encode for the render calls (scene tokens, cameras)
  int64_t renderOutput = 0;  // a render call's output kept until the next (the semantic features)
  // Reservations of the shared transformer workspace (tokens, dim, hidden): it grows to the largest.
  std::vector<std::array<int64_t, 3>> workspace;
};

// What a stage's memory terms and weights depend on: the model, its configuration, the request.
struct StageSizing {
  const PackedModel& model;
  const SparConfig& config;
  const RequestShape& shape;
};

// The totals a stage's own moment builds on (memory_estimate.cpp).
struct MemoryMoments {
  int64_t encode = 0;        // everything alive at the end of the encode, the largest transients included
  int64_t between = 0;       // what stays from the encode for the render calls
  int64_t renderOutput = 0;  // what the last render call left
};

// The label phases' inputs and outputs (model/stages/label_stages.cpp).
struct PromptEmbeddings;  // model/prompt_label_maps.h
struct LabelMapsOut;
struct PromptWork {
  const std::vector<int32_t>* ids = nullptr;  // CLIP token ids [count, 77]
  int64_t count = 0;
  PromptEmbeddings* text = nullptr;            // written by the text encoder, read by the label maps
  std::vector<float>* scores = nullptr;        // per-prompt scores appended here when not null
  LabelMapsOut* maps = nullptr;
};

// When a stage runs: in encode(), in every render call, when prompts are encoded, in label maps.
enum class StagePhase { Encode, Render, Prompts, Labels };

// What a stage's record() works with. Tensors pass between stages by name in `tensors` (the
// PyTorch reference's golden names where it has one: "img_tokens", "c2w", ...).
struct StageRun {
  Engine& engine;
  Recorder* recorder;  // the phase's shared recorder (null for stages that submit their own work)
  const Request& request;  // height and width filled in
  const SparConfig& config;
  StageModels& models;
  TransformerWorkspace& ws;
  NonFiniteWatch& watch;
  bool keepIntermediates = false;
  bool profile = false;  // per-dispatch timestamps asked for (SparPipelineOptions::profile)
  std::map<std::string, Tensor>& tensors;
  Encoded& encoded;  // host results a stage adds (SAM2.1's decisions)
  // Keeps a tensor under its golden name for tests (SparPipelineOptions::keepIntermediates).
  std::function<void(const std::string&, const Tensor&)> keep;
  // A stage that submits its own work (ownsSubmissions) reports each submission here, with the
  // wall time it took (its GPU and build times come from the recorder, under its stage name),
  // and times of work without a recorder of its own through recordTime (name, GPU, wall, build).
  std::function<void(const Recorder&, double wallMs)> submitted;
  std::function<void(const std::string&, double, double, double, const StageCounts&)> recordTime;
  // The label phases' work (label_stages.cpp): the prompts' token ids in, embeddings and maps out.
  PromptWork* prompts = nullptr;

  Recorder& rec() const;
  const Tensor& at(const std::string& name) const;
  // The tensor `name` when a stage wrote it, else an undefined one.
  Tensor optional(const std::string& name) const;
};

class PipelineStage {
 public:
  virtual ~PipelineStage() = default;
  virtual const char* name() const = 0;  // its stageTimes() name
  virtual StagePhase phase() const { return StagePhase::Encode; }
  // The tensors (StageRun::tensors) it reads and writes.
  virtual std::vector<std::string> reads() const = 0;
  virtual std::vector<std::string> writes() const = 0;
  // The packed file's top-level modules whose weights it loads for this request
  // (converter/FORMAT.md names them: "image_tokenizer", "dino", "lseg", ...).
  virtual std::vector<std::string> weightModules(const StageSizing& s) const = 0;
  virtual StageMemory memory(const StageSizing& s) const = 0;
  // The most alive at once while it runs after the encode (a render call, the text encoder, a
  // SAM2.1 view), given what is alive around it; 0 when its peak is within the encode's.
  virtual int64_t moment(const StageSizing&, const MemoryMoments&) const { return 0; }
  // Records its work on run.rec(): the pipeline submits it as one submission, its GPU time the
  // stage's. Stages that submit their own work (ownsSubmissions) do it all here.
  virtual void record(StageRun& run) = 0;
  virtual bool ownsSubmissions() const { return false; }
};

using StageList = std::vector<std::unique_ptr<PipelineStage>>;

}  // namespace spar
