#include "model/dino_v3.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>

#include "spar/error.h"
#include "engine/ops/binary.h"
#include "engine/ops/copy2d.h"
#include "engine/ops/linear.h"
#include "engine/ops/norm.h"
#include "engine/ops/patchify.h"
#include "engine/ops/rope.h"
#include "model/stack.h"

namespace spar {
namespace {

const std::string kPrefix = "dino.";

// The block weights TransformerBlock asks for (SPAR's names) and where DINOv3 keeps them under
// "dino.blocks.<i>.", with their shapes in units of E (width) and F (MLP hidden width).
enum class Dims { E, ThreeE, F, ThreeE_E, E_E, F_E, E_F };
struct BlockKey {
  const char* block;
  const char* dino;
  Dims dims;
};
constexpr BlockKey kBlockKeys[] = {
    {"norm1.weight", "norm1.weight", Dims::E},
    {"norm1.bias", "norm1.bias", Dims::E},
    {"attn.to_qkv.weight", "attn.qkv.weight", Dims::ThreeE_E},
    {"attn.to_qkv.bias", "attn.qkv.bias", Dims::ThreeE},
    {"attn.fc.weight", "attn.proj.weight", Dims::E_E},
    {"attn.fc.bias", "attn.proj.bias", Dims::E},
    {"norm2.weight", "norm2.weight", Dims::E},
    {"norm2.bias", "norm2.bias", Dims::E},
    {"mlp.mlp.0.weight", "mlp.fc1.weight", Dims::F_E},
    {"mlp.mlp.0.bias", "mlp.fc1.bias", Dims::F},
    {"mlp.mlp.2.weight", "mlp.fc2.weight", Dims::E_F},
    {"mlp.mlp.2.bias", "mlp.fc2.bias", Dims::E},
    {"ls1.gamma", "ls1.gamma", Dims::E},
    {"ls2.gamma", "ls2.gamma", Dims::E},
};

Shape shapeOf(Dims d, int64_t E, int64_t F) {
  switch (d) {
    case Dims::E: return {E};
    case Dims::ThreeE: return {3 * E};
    case Dims::F: return {F};
    case Dims::ThreeE_E: return {3 * E, E};
    case Dims::E_E: return {E, E};
    case Dims::F_E: return {F, E};
    case Dims::E_F: return {E, F};
  }
  throw Error("DINOv3: unknown weight shape");
}

// Looks TransformerBlock's names up as block i's DINOv3 tensors.
WeightLookup blockWeights(WeightSet& weights, int64_t i, int64_t E, int64_t F) {
  const std::string prefix = kPrefix + "blocks." + std::to_string(i) + ".";
  return weightLookup(weights, [prefix, E, F](const std::string& name) -> std::pair<std::string, Shape> {
    for (const BlockKey& k : kBlockKeys)
      if (name == k.block) return {prefix + k.dino, shapeOf(k.dims, E, F)};
    throw Error("DINOv3: the transformer block asks for '" + name + "', which DINOv3 does not have");
  });
}

TransformerBlockOptions optionsFor(const DinoConfig& c) {
  TransformerBlockOptions o = TransformerBlockOptions::dinov3(c.embedDim, c.headDim());
  o.mlpHidden = c.ffnHidden();
  o.lnEps = static_cast<float>(c.lnEps);
  o.qkvBias = c.qkvBias;
  o.fcBias = c.projBias;
  o.mlpBias = c.ffnBias;
  o.layerScale = c.layerScale;
  // The converter folded qkv.bias_mask into qkv.bias (converter/FORMAT.md): masking again
  // would only cost a copy of every qkv bias.
  o.maskKBias = false;
  return o;
}

}  // namespace

std::vector<double> DinoV3::ropeAngles(const DinoConfig& config, const std::vector<double>& periods, int64_t h,
                                       int64_t w) {
  const int64_t dh = config.headDim(), quarter = dh / 4;
  if (dh % 4 != 0 || static_cast<int64_t>(periods.size()) != quarter)
    throw Error("DINOv3: RoPE needs dh / 4 = " + std::to_string(quarter) + " periods, got " +
                std::to_string(periods.size()));
  double denH = static_cast<double>(h), denW = static_cast<double>(w);
  if (config.ropeNormalizeCoords == "max") denH = denW = static_cast<double>(std::max(h, w));
  else if (config.ropeNormalizeCoords == "min") denH = denW = static_cast<double>(std::min(h, w));
  else if (config.ropeNormalizeCoords != "separate")
    throw Error("DINOv3: rope_normalize_coords '" + config.ropeNormalizeCoords + "' is not implemented");

  std::vector<double> angles(static_cast<size_t>(h * w * dh));
  for (int64_t i = 0; i < h; ++i)
    for (int64_t j = 0; j < w; ++j) {
      const double coord[2] = {2.0 * ((i + 0.5) / denH) - 1.0, 2.0 * ((j + 0.5) / denW) - 1.0};
      double* row = &angles[static_cast<size_t>((i * w + j) * dh)];
      for (int axis = 0; axis < 2; ++axis)
        for (int64_t k = 0; k < quarter; ++k) {
          const double a = 2.0 * std::numbers::pi * coord[axis] / periods[k];
          row[axis * quarter + k] = a;               // [rows | cols] ...
          row[dh / 2 + axis * quarter + k] = a;      // ... tiled twice over dh
        }
    }
  return angles;
}

DinoV3::DinoV3(Engine& engine, WeightSet& weights, const DinoConfig& config)
    : engine_(engine), config_(config), options_(optionsFor(config)) {
  const int64_t E = config_.embedDim, dh = config_.headDim(), p = config_.patchSize, S = config_.storageTokens;
  if (E <= 0 || config_.numHeads <= 0 || E % config_.numHeads != 0 || dh % 4 != 0 || p < 1 || S < 0 ||
      config_.depth < 0)
    throw Error("DINOv3: unusable configuration (embed_dim " + std::to_string(E) + ", " +
                std::to_string(config_.numHeads) + " heads, patch " + std::to_string(p) + ")");

  // RoPE periods as the checkpoint stores them (float32 in the released file; the reference
  // divides by exactly these values).
  const Tensor periods = weights.require(kPrefix + "rope_embed.periods", {dh / 4}, DType::F32);
  for (float v : engine_.download(periods)) {
    if (!(v > 0.0f) || !std::isfinite(v)) throw Error("DINOv3: dino.rope_embed.periods holds a non-positive value");
    periods_.push_back(v);
  }

  std::vector<float> negMean(3), invStd(3);
  for (int c = 0; c < 3; ++c) {
    negMean[c] = -config_.mean[c];
    invStd[c] = static_cast<float>(1.0 / static_cast<double>(config_.std[c]));
  }
  negMean_ = engine_.fromFloats({3, 1, 1}, negMean);
  invStd_ = engine_.fromFloats({3, 1, 1}, invStd);

  // The conv kernel [E, 3, p, p] is a batch of E "images" of 3 x p x p: patchify turns it into
  // [E, 1, p*p*3] in the (ph pw c) order patchify gives the image patches, so the patch
  // embedding becomes one GEMM. Measured on llvmpipe, full size (8 views 256x256, E 768):
  // patchify 4 ms + linear 41 ms against 800-900 ms for conv2d's 16x16 stride-16 kernel.
  const Tensor conv = weights.require(kPrefix + "patch_embed.proj.weight", {E, 3, p, p}, DType::F32);
  patchBias_ = weights.require(kPrefix + "patch_embed.proj.bias", {E});
  patchWeight_ = engine_.tensor({E, 1, p * p * 3});
  const Tensor cls = weights.require(kPrefix + "cls_token", {1, 1, E}, DType::F32);
  prefixTokens_ = engine_.tensor({1, 1 + S, E});
  {
    Recorder rec(engine_, /*profile=*/true);  // setup dispatches: their builds are counted too
    patchify(rec, conv, patchWeight_, static_cast<int>(p));
    if (S > 0)
      concat(rec, {cls, weights.require(kPrefix + "storage_tokens", {1, S, E}, DType::F32)}, prefixTokens_, 1);
    else
      concat(rec, {cls}, prefixTokens_, 1);
    rec.run();
  }
  patchWeight_ = patchWeight_.reshape({E, p * p * 3});

  blocks_.reserve(static_cast<size_t>(config_.depth));
  for (int64_t i = 0; i < config_.depth; ++i)
    blocks_.emplace_back(engine_, options_, blockWeights(weights, i, E, options_.hidden()));
  normWeight_ = weights.require(kPrefix + "norm.weight", {E}, DType::F32);
  normBias_ = weights.require(kPrefix + "norm.bias", {E}, DType::F32);
}

const DinoV3::RopeTables& DinoV3::ropeTables(int64_t h, int64_t w) {
  auto it = rope_.find({h, w});
  if (it != rope_.end()) return it->second;
  const std::vector<double> angles = ropeAngles(config_, periods_, h, w);
  std::vector<float> s(angles.size()), c(angles.size());
  for (size_t i = 0; i < angles.size(); ++i) {
    s[i] = static_cast<float>(std::sin(angles[i]));
    c[i] = static_cast<float>(std::cos(angles[i]));
  }
  const Shape shape{h * w, config_.headDim()};
  return rope_.emplace(std::make_pair(h, w), RopeTables{engine_.fromFloats(shape, s), engine_.fromFloats(shape, c)})
      .first->second;
}

int64_t DinoV3::ownFloats(const DinoConfig& c, int64_t views, int64_t height, int64_t width) {
  const int64_t E = c.embedDim, p = c.patchSize, P = 1 + c.storageTokens, n = (height / p) * (width / p);
  const int64_t derived = 6 + E * p * p * 3 + P * E;                       // mean / std, patchWeight_, prefixTokens_
  const int64_t buffers = views * (3 * height * width + n * p * p * 3 + n * E + P * E + (P + n) * E);  // buffers()
  return derived + buffers + 2 * n * c.headDim();                          // + ropeTables()
}

DinoV3::Buffers& DinoV3::buffers(int64_t views, int64_t height, int64_t width) {
  Buffers& b = buffers_;
  if (b.views == views && b.height == height && b.width == width) return b;
  b = Buffers{};  // release the old size's memory before allocating the new one
  const int64_t E = config_.embedDim, p = config_.patchSize, P = prefixTokens(), n = (height / p) * (width / p);
  b.normalized = engine_.tensor({views, 3, height, width});
  b.patches = engine_.tensor({views, n, p * p * 3});
  b.embedded = engine_.tensor({views, n, E});
  b.prefix = engine_.tensor({views, P, E});
  b.x = engine_.tensor({views, P + n, E});
  // The prefix tokens are the same for every call: repeat them per view once.
  Recorder rec(engine_, /*profile=*/true);  // setup dispatches: their builds are counted too
  concat(rec, std::vector<Tensor>(static_cast<size_t>(views), prefixTokens_), b.prefix, 0);
  rec.run();
  b.views = views;
  b.height = height;
  b.width = width;
  return b;
}

void DinoV3::forward(Recorder& rec, const Tensor& images, const Tensor& tokens, TransformerWorkspace& ws) {
  const int64_t E = config_.embedDim, p = config_.patchSize, P = prefixTokens();
  if (images.rank() != 4 || images.dim(1) != 3 || images.dtype() != DType::F32)
    throw Error("DINOv3: images must be f32 [V, 3, H, W], got " + images.describe());
  const int64_t V = images.dim(0), H = images.dim(2), W = images.dim(3);
  if (H < p || W < p || H % p != 0 || W % p != 0)
    throw Error("DINOv3: image size " + std::to_string(H) + "x" + std::to_string(W) +
                " is not a positive multiple of the patch size " + std::to_string(p));
  const int64_t h = H / p, w = W / p, n = h * w;
  if (tokens.shape() != Shape{V, n, E} || tokens.dtype() != DType::F32)
    throw Error("DINOv3: tokens must be f32 " + shapeString({V, n, E}) + ", got " + tokens.describe());
  if (V == 0) return;

  Buffers& b = buffers(V, H, W);
  const RopeTables& tables = ropeTables(h, w);
  ws.reserve(engine_, V * (P + n), options_);

  add(rec, images, negMean_, b.normalized);
  mul(rec, b.normalized, invStd_, b.normalized);
  patchify(rec, b.normalized, b.patches, static_cast<int>(p));
  linear(rec, b.patches, patchWeight_, patchBias_, b.embedded);
  concat(rec, {b.prefix, b.embedded}, b.x, 1);

  const BlockRope rope{tables.sin, tables.cos, P};
  forwardBlocks(rec, blocks_, b.x, ws, &rope);

  // LayerNorm is per token: normalize only the patch tokens, in the output.
  slice(rec, b.x, 1, P, n, tokens);
  layerNorm(rec, tokens, normWeight_, normBias_, tokens, static_cast<float>(config_.lnEps));
}

}  // namespace spar
