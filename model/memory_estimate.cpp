#include "model/memory_estimate.h"

#include <algorithm>
#include <string>

#include "model/quantized_matrices.h"
#include "model/sam2_config.h"
#include "model/weight_set.h"

namespace spar {
namespace {

bool startsWith(const std::string& s, const char* prefix) { return s.rfind(prefix, 0) == 0; }

// Whether a request runs the stage that reads tensor `name` (by its top-level module, as
// converter/FORMAT.md names them).
bool used(const std::string& name, const MemoryQuery& q) {
  if (startsWith(name, "sam2.")) return q.refine;
  if (startsWith(name, "dino.") || startsWith(name, "cv_drp.")) return !q.assumeStatic;
  if (startsWith(name, "clip.")) return q.labels;
  if (startsWith(name, "lseg.") || startsWith(name, "semantic_") || startsWith(name, "target_pose_tokenizer_semantic"))
    return q.semantic;
  return true;
}

// What SAM2.1's refinement of one view holds at once at least (model/sam2_image_encoder.cpp,
// sam2_hiera_block.cpp, sam2_mask_decoder.cpp; views one after another, the trunk submitted
// block by block): the larger of two moments. During the first Hiera block: the 1024x1024
// input, the patch embedding and its tokens, and the block's LayerNorm, qkv, attention, MLP
// hidden and output maps. After the trunk: the four stage maps, the neck's laterals, level 2
// and image_embed, feat_s0 / feat_s1, and the decoder's upscaled map and 3 mask logits.
int64_t sam2ViewFloats(const Sam2Config& c) {
  const int64_t S = Sam2Config::kImageSize, side = c.tokenSide(), t = side * side, c0 = c.embedDim, d = c.dModel;
  const int64_t firstBlock = 3 * S * S + 2 * t * c0 + t * c0 * (1 + 3 + 1 + 4 + 1);
  int64_t afterTrunk = 0;
  for (int64_t i = 0, tokens = t, width = c0; i < 4; ++i, tokens /= 4, width *= 2) afterTrunk += tokens * (width + d);
  afterTrunk += 2 * (t / 16) * d + t * (d / 8) + (t / 4) * (d / 4) + t * (d / 8) + 3 * t;
  return std::max(firstBlock, afterTrunk);
}

}  // namespace

MemoryNeed estimateMemory(const PackedModel& model, const SparConfig& c, const MemoryQuery& q) {
  MemoryNeed need;
  for (const std::string& name : model.names()) {
    const PackedTensorInfo& t = model.info(name);
    if ((t.dtype == FileDType::U8 && !t.quantBits) || !used(name, q)) continue;  // U8: host data (CLIP's BPE table)
    if (name.size() > 7 && name.compare(name.size() - 7, 7, ".qscale") == 0) continue;  // counted with its codes
    // float tensors reach the device as f32, matrices as f16 under an fp16 matrix type, quantized
    // ones (in the file, or by the q8 / q4 rule at upload) as rows of codes and scales; ints as i32
    const bool half = q.matrixType == DType::F16 && WeightSet::isMatrix(name, t.shape) && !t.quantBits;
    if (t.quantBits)
      need.weightBytes += tensorBytes(quantizedMatrixShape(t.shape), t.quantBits == 8 ? DType::Q8 : DType::Q4);
    else if (isQuantized(q.matrixType) && isQuantizedMatrix(name, t.shape))
      need.weightBytes += tensorBytes(quantizedMatrixShape(t.shape), q.matrixType);
    else
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
  if (q.refine) {
    const auto meta = model.metadata().find("sam2_config");
    if (meta != model.metadata().end()) {
      // the refined masks of the inputs (and targets) and one view's refinement at a time
      floats += (k + (q.targetMotion ? q.targets : 0)) * hw + sam2ViewFloats(Sam2Config::fromJson(meta->second));
    }
  }
  need.activationBytes = uint64_t(floats) * 4;
  return need;
}

}  // namespace spar
