// The LSeg image encoder (`clip_vitl16_384`, frozen, eval mode) on the engine: SPAR's semantic
// features. Reference: reference/spar_reference/lseg.py (LSegEncoder = SPAR's
// LSegFeatureExtractor.extract_features with half_res).
//
//   images [V, 3, H, W] in [0, 1]  (input_norm "lseg": (x - 0.5) / 0.5 first; SPAR: "none")
//     -> patch embedding conv p x p stride p with bias       (as patchify + linear)
//     -> [cls, patches] + position embeddings                 (pretrain grid resized bilinearly,
//                                                              align_corners=False, to H/p x W/p)
//     -> timm ViT blocks 0 .. max(hooks); the residual stream after each hook block feeds
//        readout "project": GELU(Linear(cat(patch, cls)))   -> [V, W, H/16, W/16]
//        reassemble: Conv1x1, then ConvT k4 s4 / ConvT k2 s2 / nothing / Conv3x3 s2 p1
//        scratch.layerN_rn Conv3x3 (no bias)                -> l1..l4 at H/4, H/8, H/16, H/32
//     -> RefineNet fusion: path = RCU2(path + RCU1(lN)), bilinear x2 (align_corners=True),
//        out_conv 1x1; RCU(x) = x + conv2(relu(conv1(relu(x)))) with BatchNorm folded into the
//        convs' biases by the converter
//     -> head1 Conv1x1 features -> feature_dim            -> [V, feature_dim, H/2, W/2]
//
// Weights come from the packed file under "lseg." (converter/FORMAT.md). Every tensor is
// required with its expected shape at construction: a missing or mis-shaped one is a one-line
// error naming it. Everything runs as engine dispatches; the host only builds constant tables.
#pragma once
#include <array>
#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "engine/engine.h"
#include "engine/recorder.h"
#include "model/spar_config.h"
#include "model/transformer_block.h"
#include "model/weight_set.h"

namespace spar {

// The "lseg" object of the packed file's config (converter/FORMAT.md).
struct LSegConfig {
  int64_t width = 1024, depth = 24, numHeads = 16, patchSize = 16, pretrainImgSize = 384;
  double mlpRatio = 4.0, lnEps = 1e-6;
  std::array<int64_t, 4> hooks{5, 11, 17, 23};
  std::array<int64_t, 4> reassemble{256, 512, 1024, 1024};
  int64_t features = 256, featureDim = 512;
  std::string inputNorm = "none";  // "none" (SPAR) | "lseg": (x - 0.5) / 0.5

  int64_t headDim() const { return width / numHeads; }
  int64_t mlpHidden() const;  // round(width * mlp_ratio), as the converter checks it
  int64_t pretrainGrid() const { return pretrainImgSize / patchSize; }
  int64_t lastHook() const;   // blocks after it never reach the features
  // Reads config["lseg"]; throws one line "<where>: config: lseg.<field> ..." for a missing or
  // mistyped field and for options the engine does not implement.
  static LSegConfig fromJson(const nlohmann::json& config, const std::string& where);
};

class LSegEncoder {
 public:
  // Image sides must be multiples of this: the 4th hook's stride-2 conv halves H/16, and the
  // fusion doubles it back three times, so H/16 must be even (likewise W).
  static constexpr int64_t kSizeMultiple = 32;

  // Reads the sizes from config.raw["lseg"] and requires every weight.
  LSegEncoder(Engine& engine, WeightSet& weights, const SparConfig& config);
  LSegEncoder(Engine& engine, WeightSet& weights, const LSegConfig& config);

  // images: [V, 3, H, W] f32 in [0, 1] with H and W multiples of 32 (the 4th hook's stride-2
  // conv and the x2 fusion steps need an even H/16; else a one-line spar::Error); features:
  // [V, feature_dim, H/2, W/2] f32, written. ws grows to V * (1 + n) tokens if smaller.
  // Buffers of one (V, H, W) are allocated on its first call and reused while it stays; the
  // resized position embeddings are kept per (H, W).
  void forward(Recorder& rec, const Tensor& images, const Tensor& features, TransformerWorkspace& ws);

  const LSegConfig& config() const { return config_; }
  const TransformerBlockOptions& blockOptions() const { return options_; }
  // Device floats an encoder allocates beside the weight set for one forward of [V, 3, H, W]:
  // what construction derives from weights, the buffers of that size (buffers()) and its
  // position table (positions(), with the resized grid it is made from); for the memory
  // estimate (model/memory_estimate.h).
  static int64_t ownFloats(const LSegConfig& config, int64_t views, int64_t height, int64_t width);
  // Floating-point operations of one forward at [V, 3, H, W] (multiply-add = 2), for reports.
  double flops(int64_t views, int64_t height, int64_t width) const;

 private:
  struct Hook {
    Tensor readPatchW, readClsW, readB;  // project.0 split into its patch and cls halves [W, W]
    Tensor projW, projB;                 // act_postprocessN.3 as a linear [r, W]
    Tensor tailW, tailB;                 // act_postprocessN.4 (ConvT or Conv3x3) or undefined
    Tensor rnW;                          // scratch.layerN_rn [f, r, 3, 3]
  };
  struct ResidualUnit {
    Tensor conv1W, conv1B, conv2W, conv2B;  // BN folded
  };
  struct Fusion {
    ResidualUnit rcu1, rcu2;  // rcu1 unused (absent) for refinenet4
    Tensor outW, outB;
  };
  // Activations of one (V, H, W): allocated once, reused while the size stays.
  struct Buffers {
    int64_t views = -1, height = -1, width = -1;
    Tensor normalized;            // [V, 3, H, W] (input_norm "lseg" only)
    Tensor patches, embedded;     // [V, n, p*p*3], [V, n, W]
    Tensor prefix;                // [V, 1, W]: the cls token per view (filled once)
    Tensor x;                     // [V, 1 + n, W]: the residual stream
    Tensor clsRows, clsTerm;      // [V, W]
    Tensor readout;               // [V, n, W]
    Tensor projected, grid, tail; // hook scratch, largest of the four hooks
    std::array<Tensor, 4> layers; // l1..l4 [V, f, H/4 .. H/32]
    Tensor up, scratchA, scratchB;  // fusion scratch (up to [V, max(f, fd), H/4, W/4])
  };

  void loadWeights(WeightSet& weights);
  const Tensor& positions(int64_t gh, int64_t gw);  // [1 + gh*gw, W], cached per grid
  Buffers& buffers(int64_t views, int64_t height, int64_t width);
  void reassemble(Recorder& rec, Buffers& b, int hook, int64_t gh, int64_t gw);
  void residualUnit(Recorder& rec, const ResidualUnit& u, const Tensor& x, Buffers& b);
  void fuse(Recorder& rec, Buffers& b, const Tensor& features);

  Engine& engine_;
  LSegConfig config_;
  TransformerBlockOptions options_;
  Tensor patchWeight_, patchBias_;  // [W, p*p*3] in patchify's (ph pw c) order, [W]
  Tensor cls_;                      // [1, 1, W]
  Tensor posCls_, posGrid_;         // [1, W]; [1, W, g, g] channel-major for the resize
  std::vector<TransformerBlock> blocks_;
  std::array<Hook, 4> hooks_;
  std::array<Fusion, 4> fusion_;    // refinenet1..4
  Tensor headW_, headB_;            // head1 as a 1x1 conv
  std::map<std::pair<int64_t, int64_t>, Tensor> positions_;
  Buffers buffers_;
};

}  // namespace spar
