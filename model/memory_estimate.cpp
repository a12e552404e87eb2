#include "model/memory_estimate.h"

#include <string>

#include "model/weight_set.h"

namespace spar {
namespace {

bool startsWith(const std::string& s, const char* prefix) { return s.rfind(prefix, 0) == 0; }

// Whether a request runs the stage that reads tensor `name` (by its top-level module, as
// converter/FORMAT.md names them).
bool used(const std::string& name, const MemoryQuery& q) {
  if (startsWith(name, "dino.") || startsWith(name, "cv_drp.")) return !q.assumeStatic;
  if (startsWith(name, "clip.")) return q.labels;
  if (startsWith(name, "lseg.") || startsWith(name, "semantic_") || startsWith(name, "target_pose_tokenizer_semantic"))
    return q.semantic;
  return true;
}

}  // namespace

MemoryNeed estimateMemory(const PackedModel& model, const SparConfig& c, const MemoryQuery& q) {
  MemoryNeed need;
  for (const std::string& name : model.names()) {
    const PackedTensorInfo& t = model.info(name);
    if (t.dtype == FileDType::U8 || !used(name, q)) continue;  // U8: host data (CLIP's BPE table)
    // float tensors reach the device as f32, matrices as f16 under an fp16 matrix type; ints as i32
    const bool half = q.matrixType == DType::F16 && WeightSet::isMatrix(name, t.shape);
    need.weightBytes += uint64_t(t.numel()) * (half ? 2 : 4);
  }
  const int64_t v = q.views, k = q.inputs, r = q.renderChunk, h = q.height, w = q.width, d = c.d;
  const int64_t p = c.patchSize, n = (h / p) * (w / p), hw = h * w, s = c.sceneTokens;
  int64_t floats = 0;
  // image tokens, cameras, rays (all views)
  floats += 3 * v * hw + 2 * v * n * d + v * d + (v + v * n) * d + 6 * v * hw + v * n * d;
  if (!q.assumeStatic) floats += v * n * d + 2 * k * hw;  // DINOv3 tokens, CV-DRP logits and P(dynamic)
  floats += 2 * k * n * d;                                // fused and gated input tokens
  int64_t semanticTokens = 0;
  if (c.useLseg) {
    semanticTokens = k * (h / 16) * (w / 16);
    floats += k * c.semanticDim * (hw / 4) + 3 * k * hw + 2 * semanticTokens * d;
  }
  floats += (s + k * n + semanticTokens) * d;  // the scene encoder's sequence
  if (r > 0) {
    const int64_t q2 = q.semantic ? 2 * n : n;
    // queries (RGB, semantic), decoder sequence, decoded tokens, RGB patches and image, rays
    floats += r * (q2 * d + (q2 + s) * d + n * d + n * p * p * 3 + 3 * hw + 6 * hw);
    if (q.semantic) floats += r * c.semanticDim * (hw / 4);
  }
  need.activationBytes = uint64_t(floats) * 4;
  return need;
}

}  // namespace spar
