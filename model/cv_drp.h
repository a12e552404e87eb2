// CV-DRP, the cross-view dynamic region predictor (`cv_drp.estimator.*`), on the engine.
// Reference: reference/spar_reference/spar.py (FusionMLP, DPTDecoder, CVDRPFusion,
// get_view_pairs, SPAR.run_cv_drp). For the views of one subset (inputs or targets):
//
//   fused  = fusion_mlp(concat(dino, img, ray))        Linear(3D, 2D) -> GELU -> Linear(2D, D)
//   pairs  = [fused_i, fused_j] for the official pairs (i, j)  -> [P, 2n, D]
//   tokens = transformer_layers(pairs)                  SPAR blocks with QK-norm, dh = D / heads
//   pair logits = dpt_decoder(tokens as [2P, D, gh, gw]) -> [P, 2, 1, 16gh, 16gw]
//   logits[view] = mean of its pair logits (a self-pair counts once); prob = sigmoid(logits)
//
// The decoder's BatchNorms are folded into the convolutions by the converter (FORMAT.md), so
// each stage is conv + bias then GELU. All pairs run as one batch; everything is recorded as
// engine dispatches, nothing is computed on the host.
#pragma once
#include <cstdint>
#include <utility>
#include <vector>

#include "engine/engine.h"
#include "engine/recorder.h"
#include "model/spar_config.h"
#include "model/transformer_block.h"
#include "model/weight_set.h"

namespace spar {

enum class CvDrpMode { Input, Target };

// The official pairs (SPAR._get_view_pairs) of `views` subset positions: Input (i, i+1), or
// (0, 0) for a single view; Target (i, views-1-i) for i < views/2, and with an odd count the
// middle view also paired with its predecessor (mid, max(0, mid-1)), so 1 target pairs with
// itself. Throws for views < 1.
std::vector<std::pair<int64_t, int64_t>> cvDrpPairs(int64_t views, CvDrpMode mode);

// Intermediate results for tests, copied into tensors of their own (valid after the run).
struct CvDrpTrace {
  std::vector<std::pair<int64_t, int64_t>> pairs;  // positions within the subset
  Tensor pairFused;   // [P, 2n, D] fusion_mlp output of each pair
  Tensor pairTokens;  // [P, 2n, D] transformer output
  Tensor pairLogits;  // [P, 2, 1, H, W] decoder logits
};

class CvDrp {
 public:
  // Looks up and checks every weight (one-line error naming a missing or mis-shaped tensor).
  CvDrp(Engine& engine, WeightSet& weights, const SparConfig& config);

  // dino, img, ray: [V, n, D] f32 tokens of all views in sequence order, n = gh * gw;
  // views: the subset's positions (increasing); logits, prob: [K, 1, 16gh, 16gw] outputs,
  // K = views.size(). ws is reserved here for the pair batch.
  void forward(Recorder& rec, const Tensor& dino, const Tensor& img, const Tensor& ray,
               const std::vector<int64_t>& views, CvDrpMode mode, int64_t gh, int64_t gw, const Tensor& logits,
               const Tensor& prob, TransformerWorkspace& ws, CvDrpTrace* trace = nullptr);

  // How many times scratch buffers were (re)allocated: only when a call needs more than any
  // call before it.
  int allocations() const { return allocations_; }

  // The scratch floats a call over `views` views (`pairs` view pairs) at n tokens a view
  // allocates (ping, pong, pair tokens, pair logits; what planScratch and forward allocate),
  // and the pairs of a subset of `views` views in a mode: for the memory estimate
  // (model/memory_estimate.h).
  static int64_t scratchFloats(int64_t d, int64_t views, int64_t pairs, int64_t n);
  static int64_t pairCount(int64_t views, CvDrpMode mode);

 private:
  struct UpBlock {
    Tensor upW, upB, convW, convB;  // ConvTranspose(k2, s2) and Conv3x3, BN folded
  };
  // Scratch buffers, grown to the largest request seen and reused (views at their start).
  Tensor scratch(Tensor& held, const Shape& shape);
  // Sizes the ping / pong buffers for a call up front, so a call allocates at most once.
  void planScratch(int64_t views, int64_t images, int64_t n);
  void decode(Recorder& rec, const Tensor& tokens, int64_t images, int64_t gh, int64_t gw, const Tensor& out);

  Engine& engine_;
  int64_t d_;
  std::vector<TransformerBlock> blocks_;
  Tensor fuse0W_, fuse0B_, fuse2W_, fuse2B_;
  Tensor projW_, projB_;  // project.0 as a [256, D] linear (a 1x1 conv on token rows)
  std::vector<UpBlock> up_;
  Tensor finalW_, finalB_, headW_, headB_;
  Tensor pingBuf_, pongBuf_, tokenBuf_, pairLogitBuf_;
  int allocations_ = 0;
};

}  // namespace spar
