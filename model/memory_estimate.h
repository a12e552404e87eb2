// How much device memory a request needs, before any work: two bounds of the device peak that
// report.json's device_memory.peak_bytes measures (tests/test_spar_faults.cpp,
// tests/test_spar_render.cpp and tests/test_spar_full.cpp check lower <= peak <= upper, and how
// close each is). Both add up the stages the request runs (model/stages/stage_list.h), each
// stage's own terms (model/pipeline_stage.h StageMemory, beside the code that allocates them):
//
// - The lower bound: the weights the request's stages load (exact: the packed file's tensors of
//   the modules its stages load, at the precision they reach the device) plus the activations
//   the stages keep alive through an encode and one render call. A request whose lower bound
//   exceeds the device's memory cannot run and is refused before work.
// - The upper bound: the weights again, what the stages keep for the request (derived weights,
//   tables, buffers, the transformer workspace at its largest reservation), plus the largest of
//   the moments when the most is alive at once: the end of the encode (every stage's tensors
//   and transients, as the encode's one submission keeps what it recorded until it finishes),
//   and each later stage's own moment (a SAM2.1 view, CLIP's text encoder, a render
//   call, its label maps); plus allocation rounding, staging copies and im2col scratch. A
//   request whose upper bound fits the device's memory runs without running out.
#pragma once
#include <cstdint>
#include <string>

#include "engine/tensor.h"
#include "model/packed_model.h"
#include "model/pipeline_stage.h"
#include "model/spar_config.h"

namespace spar {

struct MemoryNeed {
  uint64_t weightBytes = 0;      // what the request's stages load
  uint64_t activationBytes = 0;  // what the encode keeps, plus one render call's outputs
  uint64_t upperBytes = 0;       // the upper bound of the whole peak (weights included)
  uint64_t total() const { return weightBytes + activationBytes; }  // the lower bound
};

MemoryNeed estimateMemory(const PackedModel& model, const SparConfig& config, const RequestShape& shape);

// The bytes tensor `name` of `model` takes on the device under the matrix type `matrixType`
// (WeightSet::uploadType's rule, and the tensors stages read as f32 whatever the matrix type);
// 0 for host data (CLIP's BPE table) and for a quantized matrix's scales (counted with its codes).
uint64_t deviceWeightBytes(const PackedModel& model, const std::string& name, DType matrixType);

}  // namespace spar
