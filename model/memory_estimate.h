// How much device memory a request needs at least, before any work: the weights it will load
// (exact, from the packed file's tensors of the stages the request runs, at the precision they
// reach the device) plus the activations the pipeline keeps alive through an encode and one
// render chunk (the tensors SparPipeline::encode and Renderer::batch allocate, from the same
// shapes). Stage-internal scratch (transformer workspaces, convolution buffers) is not counted,
// so this is a lower bound: report.json's device_memory.peak_bytes is the measured total
// (tests/test_spar_faults.cpp checks estimate <= peak, and how close). A request whose lower
// bound exceeds the device's memory cannot run and is refused before work with this figure.
#pragma once
#include <cstdint>

#include "engine/tensor.h"
#include "model/packed_model.h"
#include "model/spar_config.h"

namespace spar {

struct MemoryNeed {
  uint64_t weightBytes = 0;      // what the request's stages load
  uint64_t activationBytes = 0;  // what the encode keeps, plus one render chunk
  uint64_t total() const { return weightBytes + activationBytes; }
};

struct MemoryQuery {
  int64_t views = 0, inputs = 0, targets = 0;
  int64_t renderChunk = 0;  // views rendered per render call (targets, or a --path chunk)
  int64_t height = 0, width = 0;
  bool assumeStatic = false;
  bool semantic = false;    // semantic features rendered (models with the semantic branch)
  bool labels = false;      // CLIP's text encoder loaded (prompts)
  bool refine = false;      // SAM2.1's refinement (a model packed with it): its weights and maps
  bool targetMotion = false;  // the targets' masks too (refined with them)
  DType matrixType = DType::F32;
};

MemoryNeed estimateMemory(const PackedModel& model, const SparConfig& config, const MemoryQuery& query);

}  // namespace spar
