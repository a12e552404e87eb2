#include "model/memory_estimate.h"

#include <algorithm>
#include <set>
#include <string>
#include <vector>

#include "model/nonfinite_watch.h"
#include "model/quantized_matrices.h"
#include "model/stages/stage_list.h"
#include "model/weight_set.h"

namespace spar {
namespace {

bool startsWith(const std::string& s, const char* prefix) { return s.rfind(prefix, 0) == 0; }
bool contains(const std::string& s, const char* part) { return s.find(part) != std::string::npos; }

// Matrices the stages read as f32 whatever the matrix type (an explicit DType::F32 in their
// require calls): every convolution kernel (conv2d reads f32 kernels; LSeg's quantized ones
// excepted, quantizedness is checked first) but LSeg's 1x1 projections after the readouts
// (act_postprocess{k}.3, read as linear layers: lseg.cpp), CV-DRP's DPT decoder (cv_drp.cpp),
// LSeg's readout projections (split into two halves) and CLIP's text projection (clip_text.cpp).
bool readAsF32(const std::string& name, const Shape& shape) {
  const bool lseg = startsWith(name, "lseg.");
  if (shape.size() == 4) return !(lseg && contains(name, ".act_postprocess") && contains(name, ".3.weight"));
  return startsWith(name, "cv_drp.estimator.dpt_decoder.") || (lseg && contains(name, ".project.0.weight")) ||
         name == "clip.text_projection";
}

// The transformer workspace (model/transformer_block.cpp TransformerWorkspace::reserve): two
// narrow buffers of the largest tokens x dim and one of the largest tokens x max(3 dim, hidden)
// over the request's reservations.
struct Workspace {
  int64_t narrow = 0, wide = 0;
  void reserve(int64_t tokens, int64_t dim, int64_t hidden) {
    tokens = std::max<int64_t>(tokens, 1);
    narrow = std::max(narrow, tokens * dim);
    wide = std::max(wide, tokens * std::max(3 * dim, hidden));
  }
  int64_t floats() const { return 2 * narrow + wide; }
};

}  // namespace

uint64_t deviceWeightBytes(const PackedModel& model, const std::string& name, DType matrixType) {
  const PackedTensorInfo& t = model.info(name);
  if (t.dtype == FileDType::U8 && !t.quantBits) return 0;  // host data (CLIP's BPE table)
  if (name.size() > 7 && name.compare(name.size() - 7, 7, ".qscale") == 0) return 0;  // counted with its codes
  if (t.quantBits) return tensorBytes(quantizedMatrixShape(t.shape), t.quantBits == 8 ? DType::Q8 : DType::Q4);
  const bool matrix = WeightSet::isMatrix(name, t.shape);
  if (matrix && isQuantized(matrixType) && isQuantizedMatrix(name, t.shape))
    return tensorBytes(quantizedMatrixShape(t.shape), matrixType);
  if (matrix && matrixType == DType::F16 && !readAsF32(name, t.shape)) return uint64_t(t.numel()) * 2;
  return uint64_t(t.numel()) * 4;  // f32, and integers as i32
}

namespace {

// The weights of the modules the stages load (their tensors at the request's precision): the
// total, the largest (a staging copy's size), and how many reach the device.
struct WeightTotals {
  uint64_t bytes = 0, largest = 0;
  int64_t tensors = 0;
};

WeightTotals weightTotals(const StageSizing& s, const StageList& list) {
  std::set<std::string> modules;
  for (const auto& stage : list)
    for (const std::string& m : stage->weightModules(s)) modules.insert(m);
  WeightTotals w;
  for (const std::string& name : s.model.names()) {
    if (!modules.count(name.substr(0, name.find('.')))) continue;
    const uint64_t bytes = deviceWeightBytes(s.model, name, s.shape.matrixType);
    w.bytes += bytes;
    w.largest = std::max(w.largest, bytes);
    w.tensors += bytes > 0;
  }
  return w;
}

// The activation terms of the stages, added up: the lower bound's floats, what the stages keep
// for the request, and the moments of the upper bound.
struct ActivationTotals {
  int64_t lower = 0, kept = 0, moment = 0, renderOutput = 0;
};

ActivationTotals activationTotals(const StageSizing& s, const StageList& list) {
  ActivationTotals a;
  a.kept = NonFiniteWatch::kSlots;  // the pipeline's non-finite watch (model/nonfinite_watch.h)
  Workspace ws;
  MemoryMoments around;
  int64_t transient = 0;
  for (const auto& stage : list) {
    const StageMemory m = stage->memory(s);
    a.lower += m.kept;
    a.kept += m.own;
    around.encode += m.atEncodeEnd;
    // The encode's stages share one submission, which keeps every tensor it recorded until it
    // has run: their transients are all alive at its end (a stage that submits its own work
    // splits it, so the sum is an upper bound there).
    transient += m.transient;
    around.between += m.forRenders;
    around.renderOutput += m.renderOutput;
    for (const auto& [tokens, dim, hidden] : m.workspace) ws.reserve(tokens, dim, hidden);
  }
  a.kept += ws.floats();
  around.encode += transient;
  a.moment = around.encode;
  for (const auto& stage : list) a.moment = std::max(a.moment, stage->moment(s, around));
  a.renderOutput = around.renderOutput;
  return a;
}

}  // namespace

MemoryNeed estimateMemory(const PackedModel& model, const SparConfig& c, const RequestShape& q) {
  const StageSizing sizing{model, c, q};
  const StageList list = pipelineStages(sizing);
  const WeightTotals weights = weightTotals(sizing, list);
  const ActivationTotals a = activationTotals(sizing, list);
  MemoryNeed need;
  need.weightBytes = weights.bytes;
  need.activationBytes = uint64_t(a.lower) * 4;
  // Allocation rounding (engine.cpp Engine::tensor: 16-byte multiples, 256 bytes more, 16 more
  // for a power of two) for each weight and up to a few thousand activations
  uint64_t upper = weights.bytes + uint64_t(a.kept + a.moment) * 4 + 288ull * uint64_t(weights.tensors + 4096);
  if (q.staging) {
    // the largest single copy through a staging buffer: a weight, the images, a download
    const int64_t hw = q.height * q.width, views = std::max<int64_t>({q.renderChunk, q.targets, 1});
    upper += std::max<uint64_t>({weights.largest, uint64_t(3 * q.views * hw) * 4, uint64_t(3 * views * hw) * 4,
                                 uint64_t(a.renderOutput) * 4,
                                 uint64_t(views * std::max<int64_t>(q.prompts, 1) * (hw / 4)) * 4});
  }
  // engine/ops/conv2d.cpp, conv2dAsIm2colGemm: the patches, in the scratch of each recorder
  // that records a convolution (Recorder::scratch), of which two may be alive at once (a
  // stage's and a setup's inside it)
  upper += 2 * q.im2colScratchBytes;
  need.upperBytes = std::max<uint64_t>(upper, q.peakBefore);
  return need;
}

}  // namespace spar
