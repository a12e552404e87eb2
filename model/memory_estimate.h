// How much device memory a request needs, before any work: two bounds of the device peak that
// report.json's device_memory.peak_bytes measures (tests/test_spar_faults.cpp,
// tests/test_spar_render.cpp and tests/test_spar_full.cpp check lower <= peak <= upper, and how
// close each is).
//
// - The lower bound: the weights the request's stages load (exact: the packed file's tensors
//   of the stages the request runs, at the precision they reach the device) plus the
//   activations the pipeline keeps alive through an encode and one render call. A request
//   whose lower bound exceeds the device's memory cannot run and is refused before work.
// - The upper bound: the weights again, what the stages derive from them and keep (split or
//   repacked copies, position and RoPE tables), each stage's buffers at the request's sizes
//   (the transformer workspace at its largest reservation, CV-DRP's, DINOv3's and LSeg's
//   buffers), plus the largest of the moments when the most is alive at once: the end of the
//   encode (every encode-scope tensor and every stage's transients, as one submission keeps
//   what it recorded until it finishes), a SAM2.1 refinement of one view (the Hiera block with
//   the largest transients, or the neck and mask decoder), CLIP's text encoder, a render call
//   (all its views' transients at once, as its batches share one submission) and its label
//   maps. Each term follows the code that allocates it (named beside it in the .cpp), so
//   a request whose upper bound fits the device's memory runs without running out.
#pragma once
#include <cstdint>

#include "engine/tensor.h"
#include "model/packed_model.h"
#include "model/spar_config.h"

namespace spar {

struct MemoryNeed {
  uint64_t weightBytes = 0;      // what the request's stages load
  uint64_t activationBytes = 0;  // what the encode keeps, plus one render call's outputs
  uint64_t upperBytes = 0;       // the upper bound of the whole peak (weights included)
  uint64_t total() const { return weightBytes + activationBytes; }  // the lower bound
};

struct MemoryQuery {
  int64_t views = 0, inputs = 0, targets = 0;
  int64_t renderChunk = 0;  // views rendered per render call (targets, or a --path chunk)
  int64_t height = 0, width = 0;
  bool assumeStatic = false;
  bool semantic = false;    // semantic features rendered (models with the semantic branch)
  bool labels = false;      // CLIP's text encoder loaded (prompts)
  int64_t prompts = 0;      // how many label prompts (with labels)
  bool refine = false;      // SAM2.1's refinement (a model packed with it): its weights and maps
  bool targetMotion = false;  // the targets' masks too (refined with them)
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

MemoryNeed estimateMemory(const PackedModel& model, const SparConfig& config, const MemoryQuery& query);

// The bytes tensor `name` of `model` takes on the device under the matrix type `matrixType`
// (WeightSet::uploadType's rule, and the tensors stages read as f32 whatever the matrix type);
// 0 for host data (CLIP's BPE table) and for a quantized matrix's scales (counted with its codes).
uint64_t deviceWeightBytes(const PackedModel& model, const std::string& name, DType matrixType);

}  // namespace spar
