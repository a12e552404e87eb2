// The DINOv3 ViT backbone (frozen, eval mode) on the engine: the patch tokens CV-DRP reads.
// Reference: reference/spar_reference/dino_v3.py (DinoV3 = SPAR's DINOv3FeatureExtractor).
//
//   images [V, 3, H, W] in [0, 1]
//     -> (x - mean) / std per channel                      (config mean / std, ImageNet)
//     -> patch embedding: conv p x p stride p with bias     (as patchify + linear)
//     -> [cls, storage tokens, patches]                     (prefix of 1 + S tokens)
//     -> depth x TransformerBlock (options dinov3) with RoPE on q, k of the patch tokens
//     -> drop the prefix, final LayerNorm -> tokens [V, (H/p) * (W/p), E]
//
// Weights come from the packed file under "dino." (converter/FORMAT.md; the k-bias mask is
// already folded into attn.qkv.bias there). Every tensor is required with its expected shape
// at construction, so a missing or mis-shaped one is a one-line error naming it.
#pragma once
#include <cstdint>
#include <map>
#include <utility>
#include <vector>

#include "engine/engine.h"
#include "engine/recorder.h"
#include "model/spar_config.h"
#include "model/transformer_block.h"
#include "model/weight_set.h"

namespace spar {

class DinoV3 {
 public:
  DinoV3(Engine& engine, WeightSet& weights, const DinoConfig& config);

  // images: [V, 3, H, W] f32 in [0, 1] with H and W multiples of the patch size (else a
  // one-line spar::Error; the reference would resize such images bilinearly, which SPAR's
  // prepared images never need); tokens: [V, (H/p) * (W/p), E] f32, written. Records dispatches
  // into rec; ws grows to V * (prefix + patches) tokens if it is smaller. Buffers for one
  // image size are allocated on its first call and reused by later calls of that size.
  void forward(Recorder& rec, const Tensor& images, const Tensor& tokens, TransformerWorkspace& ws);

  const DinoConfig& config() const { return config_; }
  int64_t prefixTokens() const { return 1 + config_.storageTokens; }  // cls + storage tokens
  const TransformerBlockOptions& blockOptions() const { return options_; }

  // The RoPE angles of a grid of h x w patches, [h * w, dh] row-major, in double, as the
  // reference builds them: per token (row i, column j) the coordinates 2 (i + 0.5) / h - 1 and
  // 2 (j + 0.5) / w - 1 ("separate"; "max" / "min" divide by max(h, w) / min(h, w)), angles
  // 2 pi coord / period_k for k < dh/4, laid out [rows | cols] and tiled twice over dh.
  static std::vector<double> ropeAngles(const DinoConfig& config, const std::vector<double>& periods, int64_t h,
                                        int64_t w);

  // Device floats an encoder allocates beside the weight set for one call of [V, 3, H, W]:
  // what construction derives from weights, the buffers of that size (buffers()) and its RoPE
  // tables; for the memory estimate (model/memory_estimate.h).
  static int64_t ownFloats(const DinoConfig& config, int64_t views, int64_t height, int64_t width);

 private:
  struct RopeTables {
    Tensor sin, cos;  // [h * w, dh] f32
  };
  // Activations of one (V, H, W): allocated once, reused while the size stays.
  struct Buffers {
    int64_t views = -1, height = -1, width = -1;
    Tensor normalized;  // [V, 3, H, W]
    Tensor patches;     // [V, n, p * p * 3]
    Tensor embedded;    // [V, n, E]
    Tensor prefix;      // [V, 1 + S, E]: cls and storage tokens repeated per view (filled once)
    Tensor x;           // [V, 1 + S + n, E]: the residual stream
  };
  const RopeTables& ropeTables(int64_t h, int64_t w);
  Buffers& buffers(int64_t views, int64_t height, int64_t width);

  Engine& engine_;
  DinoConfig config_;
  TransformerBlockOptions options_;
  std::vector<double> periods_;  // [dh / 4], the checkpoint's rope_embed.periods
  Tensor negMean_, invStd_;      // [3, 1, 1]
  Tensor patchWeight_;           // [E, p * p * 3]: the conv kernel in patchify's (ph pw c) order
  Tensor patchBias_;             // [E]
  Tensor prefixTokens_;          // [1 + S, E]
  Tensor normWeight_, normBias_;  // final LayerNorm
  std::vector<TransformerBlock> blocks_;
  std::map<std::pair<int64_t, int64_t>, RopeTables> rope_;
  Buffers buffers_;
};

}  // namespace spar
