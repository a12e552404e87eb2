#include "model/memory_estimate.h"

#include <algorithm>
#include <string>
#include <vector>

#include "model/clip_text.h"
#include "model/cv_drp.h"
#include "model/dino_v3.h"
#include "model/lseg.h"
#include "model/quantized_matrices.h"
#include "model/sam2_config.h"
#include "model/weight_set.h"

namespace spar {
namespace {

bool startsWith(const std::string& s, const char* prefix) { return s.rfind(prefix, 0) == 0; }
bool contains(const std::string& s, const char* part) { return s.find(part) != std::string::npos; }

// Whether a request runs the stage that reads tensor `name` (by its top-level module, as
// converter/FORMAT.md names them; model/spar_pipeline.cpp runs LSeg and the semantic tokens
// whenever the model has LSeg, and the renderer's semantic queries whenever it decodes them).
bool used(const std::string& name, const SparConfig& c, const MemoryQuery& q) {
  if (startsWith(name, "sam2.")) return q.refine;
  if (startsWith(name, "dino.") || startsWith(name, "cv_drp.")) return !q.assumeStatic;
  if (startsWith(name, "clip.")) return q.labels;
  if (startsWith(name, "lseg.") || startsWith(name, "semantic_proj.")) return c.useLseg;
  if (startsWith(name, "target_pose_tokenizer_semantic")) return c.semanticDecoding();
  if (startsWith(name, "semantic_token_decoder.") || startsWith(name, "semantic_feature_expansion."))
    return q.semantic;
  return true;
}

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

// What SAM2.1's refinement of one view holds at once at least (for the lower bound): the larger
// of two moments. During the first Hiera block: the 1024x1024 input, the patch embedding and
// its tokens, and the block's LayerNorm, qkv, attention, MLP hidden and output maps. After the
// trunk: the four stage maps, the neck's laterals, level 2 and image_embed, feat_s0 / feat_s1,
// and the decoder's upscaled map and 3 mask logits.
int64_t sam2ViewFloatsAtLeast(const Sam2Config& c) {
  const int64_t S = c.imageSize, side = c.tokenSide(), t = side * side, c0 = c.embedDim, d = c.dModel;
  const int64_t firstBlock = 3 * S * S + 2 * t * c0 + t * c0 * (1 + 3 + 1 + 4 + 1);
  int64_t afterTrunk = 0;
  for (int64_t i = 0, tokens = t, width = c0; i < 4; ++i, tokens /= 4, width *= 2) afterTrunk += tokens * (width + d);
  afterTrunk += 2 * (t / 16) * d + t * (d / 8) + (t / 4) * (d / 4) + t * (d / 8) + 3 * t;
  return std::max(firstBlock, afterTrunk);
}

// What SAM2.1's refinement of one view holds at once at most (model/sam2_image_encoder.cpp,
// sam2_hiera_block.cpp, sam2_mask_decoder.cpp; views one after another). The trunk is submitted
// block by block: during block i, the 1024x1024 input, the patch embedding and its first tokens,
// the stage maps so far, the block's input and output and its own transients (sam2HieraBlock's
// tensors). Then the neck and the decoder in one submission: the stage maps, the input and the
// embedding, the laterals, level 2, image_embed, feat_s0 / feat_s1, and the decoder's maps (the
// prompt's downscaling, the dense embedding and keys, two two-way layers and the final
// attention at up to d wide, the upscaling, the mask logits).
int64_t sam2ViewFloats(const Sam2Config& c, int64_t hw) {
  const int64_t S = c.imageSize, side = c.tokenSide(), t = side * side, C0 = c.embedDim, d = c.dModel;
  const int64_t s2 = t / 16, base = 3 * S * S + 2 * t * C0;  // input, embedded, the first x
  const std::vector<int64_t> ends = c.stageEnds();
  const std::vector<Sam2BlockSpec> blocks = c.blocks();
  int64_t stages = 0, largestBlock = 0, h = side, w = side;
  for (size_t i = 0; i < blocks.size(); ++i) {
    const Sam2BlockSpec& b = blocks[i];
    const int64_t D = b.dim, Do = b.dimOut, T = h * w;
    const int64_t ho = b.qPool ? h / 2 : h, wo = b.qPool ? w / 2 : w, To = ho * wo;
    const int64_t win = b.window;
    const int64_t windowed = win > 0 ? ((h + win - 1) / win) * ((w + win - 1) / win) * win * win : T;
    const int64_t qTokens = b.qPool ? windowed / 4 : windowed;
    int64_t own = T * D;                                 // xn
    if (D != Do) own += T * Do + To * Do;                // projected, shortcut
    if (win > 0) own += windowed * D + To * Do;          // windows, merged
    own += 3 * windowed * Do;                            // qkv
    if (b.qPool) own += windowed * Do + qTokens * Do;    // q alone, pooled
    own += 2 * qTokens * Do + To * Do + 4 * To * Do + To * Do;  // attended, projected, yn, hidden, MLP out
    largestBlock = std::max(largestBlock, stages + T * D + To * Do + own);
    if (std::find(ends.begin(), ends.end(), int64_t(i)) != ends.end()) stages += To * Do;  // the stage maps stay
    h = ho;
    w = wo;
  }
  // the laterals of the four levels (t, t/4, t/16, t/64 tokens, d wide), level 2, image_embed,
  // feat_s0 / feat_s1
  const int64_t neck = (t + t / 4 + t / 16 + t / 64) * d + 2 * s2 * d + t * d / 8 + t * d / 16;
  const int64_t prompt = 2 * hw + 2 * t + 3 * 4 * (t / 4) + 2 * 16 * s2;  // binary, probs, prompt map, downscaling
  // the two-way layers and the final attention (queries, keys and values of the image tokens at
  // the cross-attention's width d / 2), the dense embedding and keys, the upscaling, the logits
  const int64_t decoder = s2 * (19 * d + 10 * (d / 2)) + 2 * t;
  return base + std::max(largestBlock, stages + neck + prompt + decoder);
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

MemoryNeed estimateMemory(const PackedModel& model, const SparConfig& c, const MemoryQuery& q) {
  MemoryNeed need;
  uint64_t largestWeight = 0;
  int64_t weightTensors = 0;
  for (const std::string& name : model.names()) {
    if (!used(name, c, q)) continue;
    const uint64_t bytes = deviceWeightBytes(model, name, q.matrixType);
    need.weightBytes += bytes;
    largestWeight = std::max(largestWeight, bytes);
    weightTensors += bytes > 0;
  }

  // ---- the lower bound: what the pipeline keeps through an encode and one render call
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
    const int64_t q2 = c.semanticDecoding() ? 2 * n : n;
    // queries (RGB, semantic), decoder sequence, decoded tokens, RGB patches and image, rays
    floats += r * (q2 * d + (q2 + s) * d + n * d + n * p * p * 3 + 3 * hw + 6 * hw);
    if (q.semantic) floats += r * c.semanticDim * (hw / 4);
  }
  const auto sam2 = model.metadata().find("sam2_config");
  const bool refine = q.refine && sam2 != model.metadata().end();
  const Sam2Config sam2Config = refine ? Sam2Config::fromJson(sam2->second) : Sam2Config{};
  const int64_t motionViews = k + (q.targetMotion ? q.targets : 0);
  if (refine) floats += motionViews * hw + sam2ViewFloatsAtLeast(sam2Config);
  need.activationBytes = uint64_t(floats) * 4;

  // ---- the upper bound
  const int64_t t = q.targets, rMax = std::max<int64_t>({r, t, 1}), ns = c.useLseg ? (h / 16) * (w / 16) : 0;
  const int64_t semDim = c.semanticDim, hid = c.semanticHidden, sceneRows = s + k * n + k * ns;
  Workspace ws;
  int64_t kept = 0;    // for the whole request: stage buffers, tables, derived weights
  // view_tokens.cpp: the image and camera codes (per view count), gating.cpp: its concat and
  // hidden buffers and code tables (the image grid, LSeg's when it differs), the non-finite
  // watch's counters, the cameras (st.c2w, st.fxfycxcy: old and new at a second encode)
  kept += v * n * d + v * d + 3 * k * n * d + (n + 1) * d + (ns + 1) * d + 32 + 2 * 20 * v;
  ws.reserve(v + v * n, d, 4 * d);  // pose_estimator.cpp
  if (!q.assumeStatic) {
    kept += DinoV3::ownFloats(c.dino, v, h, w) + c.dino.depth * 3 * c.dino.embedDim;  // + masked qkv biases
    const int64_t nd = (h / c.dino.patchSize) * (w / c.dino.patchSize);
    ws.reserve(v * (1 + c.dino.storageTokens + nd), c.dino.embedDim, c.dino.ffnHidden());  // dino_v3.cpp
    // cv_drp.cpp: the inputs' call, then the targets' in the same submission (a larger scratch
    // or workspace for the targets leaves the inputs' pending beside it: both counted)
    const int64_t pairsIn = CvDrp::pairCount(k, CvDrpMode::Input);
    kept += CvDrp::scratchFloats(d, k, pairsIn, n);
    Workspace in;
    in.reserve(2 * pairsIn * n, d, 4 * d);
    ws.reserve(2 * pairsIn * n, d, 4 * d);
    if (q.targetMotion && t > 0) {
      const int64_t pairsT = CvDrp::pairCount(t, CvDrpMode::Target);
      kept += CvDrp::scratchFloats(d, t, pairsT, n) + in.floats();
      ws.reserve(2 * pairsT * n, d, 4 * d);
    }
  }
  if (c.useLseg) {
    const LSegConfig lc = LSegConfig::fromJson(c.raw, "memory estimate");
    kept += LSegEncoder::ownFloats(lc, k, h, w);
    ws.reserve(k * (1 + (h / lc.patchSize) * (w / lc.patchSize)), lc.width, lc.mlpHidden());  // lseg.cpp
  }
  ws.reserve(sceneRows, d, 4 * d);  // scene_encoder.cpp
  const int64_t queries = c.semanticDecoding() ? 2 * n : n;
  ws.reserve(std::min<int64_t>(rMax, 4) * (queries + s), d, 4 * d);  // renderer.cpp: batches of 4 views
  kept += ws.floats();

  // The moments. The encode (spar_pipeline.cpp encode()): every encode-scope tensor (all alive
  // by its end), plus the largest stage's own transients (each stage's submission keeps what it
  // recorded until it runs, and runs before the next stage records)
  int64_t encode = 3 * v * hw + 3 * v * n * d + v * d + (v + v * n) * d + 6 * v * hw;  // images, raw, tokens, cam, enc, rays
  if (!q.assumeStatic) encode += v * n * d + 2 * k * hw + (q.targetMotion ? 2 * t * hw : 0);  // DINOv3 tokens, masks
  encode += 2 * k * n * d;                                             // fused and gated input tokens
  int64_t transients = std::max({3 * v * hw + 3 * v * hw + v * n * d + v * d,  // image_tokens: scaled, patches, hidden
                                 d + 1 + (v - 1) * (3 * d + 9),                // the pose head
                                 6 * v * hw,                                   // rays: patches
                                 k * n});                                      // gating: dynamic patches
  if (c.useLseg) {
    const int64_t half = hw / 4;
    encode += k * semDim * half + 3 * k * hw + 2 * k * ns * d;          // LSeg features and input images, semantic tokens
    transients = std::max(transients, k * ns + k * (semDim + 6) * (half + 2 * ns));  // their concat, pooling, rows
  }
  encode += 2 * sceneRows * d + transients;  // the scene sequence (kept to the render) and its input
  if (refine) encode += 2 * motionViews * hw;  // refined masks of the views
  int64_t moment = encode;
  if (refine) {
    // during the refinement (after CV-DRP): the views' images, prompts, binary and refined maps
    const int64_t around = 3 * motionViews * hw + 4 * motionViews * hw;
    const int64_t t2 = sam2Config.tokenSide() * sam2Config.tokenSide();
    kept += t2 * sam2Config.embedDim + (t2 / 16) * sam2Config.dModel + 6 * sam2Config.dModel;  // position table, dense PE, tokens
    moment = std::max(moment, encode + around + sam2ViewFloats(sam2Config, hw));
  }
  // Between the encode and the renders: the scene sequence and the cameras
  const int64_t between = sceneRows * d + 20 * v;
  const int64_t features = q.semantic ? rMax * semDim * (hw / 4) : 0;
  if (q.labels && c.raw.contains("clip")) {
    // prompt_label_maps.cpp / clip_text.cpp: the projection's copy, the embeddings, the token
    // rows of every prompt at the context length, and CLIP's own workspace
    const ClipTextConfig cc = ClipTextConfig::fromJson(c.raw.at("clip"), "memory estimate");
    const int64_t rows = std::max<int64_t>(q.prompts, 1) * cc.contextLength, wc = cc.width;
    const int64_t clip = cc.embedDim * wc + 2 * q.prompts * cc.embedDim + 2 * rows + rows * wc +
                         2 * std::max<int64_t>(q.prompts, 1) * wc + 2 * rows * wc + rows * 4 * wc;
    moment = std::max(moment, between + clip);
  }
  // A render call (spar_pipeline.cpp renderRays, renderer.cpp): its cameras, rays and images,
  // and every view's queries, ray patches, decoder sequence, tokens and RGB patches (and the
  // semantic head's maps) at once; the previous call's features until the new ones replace them
  int64_t perView = 3 * n * d + (queries + s) * d + 6 * hw + 3 * hw;
  if (c.semanticDecoding()) perView += n * d + 6 * hw;
  if (q.semantic) perView += 7 * n * d + 2 * hid * hw + hid * (hw / 4);
  const int64_t render = between + 20 * rMax + 9 * rMax * hw + 2 * features + rMax * perView;
  moment = std::max(moment, render);
  if (q.labels) {
    // label_maps.cpp: the maps, the scores, the normalized features and prompts
    const int64_t labels = between + features + rMax * hw + 2 * rMax * q.prompts * (hw / 4) + features +
                           q.prompts * semDim;
    moment = std::max(moment, labels);
  }

  // Allocation rounding (engine.cpp Engine::tensor: 16-byte multiples, 256 bytes more, 16 more
  // for a power of two) for each weight and up to a few thousand activations
  uint64_t upper = need.weightBytes + uint64_t(kept + moment) * 4 + 288ull * uint64_t(weightTensors + 4096);
  if (q.staging) {
    // the largest single copy through a staging buffer: a weight, the images, a download
    const uint64_t largest = std::max<uint64_t>(
        {largestWeight, uint64_t(3 * v * hw) * 4, uint64_t(3 * rMax * hw) * 4, uint64_t(features) * 4,
         uint64_t(rMax * std::max<int64_t>(q.prompts, 1) * (hw / 4)) * 4});
    upper += largest;
  }
  // engine/ops/conv2d.cpp, conv2dAsIm2colGemm: the patches, in the scratch of each recorder
  // that records a convolution (Recorder::scratch), of which two may be alive at once (a
  // stage's and a setup's inside it)
  upper += 2 * q.im2colScratchBytes;
  need.upperBytes = std::max<uint64_t>(upper, q.peakBefore);
  return need;
}

}  // namespace spar
