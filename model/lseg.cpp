// The LSeg image encoder on the engine (model/lseg.h).
#include "model/lseg.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "spar/error.h"
#include "engine/ops/binary.h"
#include "engine/ops/conv2d.h"
#include "engine/ops/conv_transpose2d.h"
#include "engine/ops/copy2d.h"
#include "engine/ops/linear.h"
#include "engine/ops/patchify.h"
#include "engine/ops/resize.h"
#include "engine/ops/unary.h"
#include "model/stack.h"

namespace spar {
namespace {

const std::string kPrefix = "lseg.";
const std::string kVit = kPrefix + "pretrained.model.";

// What follows the 1x1 conv of each hook (act_postprocess1..4 index 4) and the resolution it
// leaves, relative to the token grid: ConvT k4 s4 (x4), ConvT k2 s2 (x2), nothing, Conv3x3 s2 p1.
enum class Tail { ConvT, None, Conv };
struct HookTail {
  Tail kind;
  int kernel;
  int up, down;  // output size = grid * up / down
};
constexpr HookTail kTails[4] = {
    {Tail::ConvT, 4, 4, 1}, {Tail::ConvT, 2, 2, 1}, {Tail::None, 0, 1, 1}, {Tail::Conv, 3, 1, 2}};

// TransformerBlock's names, where timm's ViT block keeps them under "blocks.<i>.", and their
// shapes in units of the width W and the MLP width F (0: no second dimension).
struct BlockKey {
  const char* block;
  const char* timm;
  int rowsW, rowsF, colsW, colsF;  // rows = rowsW * W + rowsF * F, likewise cols
};
constexpr BlockKey kBlockKeys[] = {
    {"norm1.weight", "norm1.weight", 1, 0, 0, 0},       {"norm1.bias", "norm1.bias", 1, 0, 0, 0},
    {"attn.to_qkv.weight", "attn.qkv.weight", 3, 0, 1, 0}, {"attn.to_qkv.bias", "attn.qkv.bias", 3, 0, 0, 0},
    {"attn.fc.weight", "attn.proj.weight", 1, 0, 1, 0},  {"attn.fc.bias", "attn.proj.bias", 1, 0, 0, 0},
    {"norm2.weight", "norm2.weight", 1, 0, 0, 0},       {"norm2.bias", "norm2.bias", 1, 0, 0, 0},
    {"mlp.mlp.0.weight", "mlp.fc1.weight", 0, 1, 1, 0}, {"mlp.mlp.0.bias", "mlp.fc1.bias", 0, 1, 0, 0},
    {"mlp.mlp.2.weight", "mlp.fc2.weight", 1, 0, 0, 1}, {"mlp.mlp.2.bias", "mlp.fc2.bias", 1, 0, 0, 0},
};

// Block i's tensors, each required with its expected shape (a missing or mis-shaped one is a
// one-line error naming it).
WeightLookup blockWeights(WeightSet& weights, int64_t i, int64_t W, int64_t F) {
  const std::string prefix = kVit + "blocks." + std::to_string(i) + ".";
  return weightLookup(weights, [prefix, W, F](const std::string& name) -> std::pair<std::string, Shape> {
    for (const BlockKey& k : kBlockKeys) {
      if (name != k.block) continue;
      const int64_t rows = k.rowsW * W + k.rowsF * F, cols = k.colsW * W + k.colsF * F;
      return {prefix + k.timm, cols > 0 ? Shape{rows, cols} : Shape{rows}};
    }
    throw Error("LSeg: the transformer block asks for '" + name + "', which timm's ViT block does not have");
  });
}

// timm's ViT block (vit_large_patch16_384 as lang-seg runs it): LayerNorm with bias, biases on
// qkv, proj, fc1 and fc2, exact GELU, no QK-norm, no LayerScale.
TransformerBlockOptions timmOptions(const LSegConfig& c) {
  TransformerBlockOptions o = TransformerBlockOptions::spar(c.width, c.headDim());
  o.mlpHidden = c.mlpHidden();
  o.lnBias = o.qkvBias = o.fcBias = o.mlpBias = true;
  o.qkNorm = false;
  o.lnEps = static_cast<float>(c.lnEps);
  o.activation = Activation::Gelu;
  return o;
}

// Config fields, one line per problem.
struct Fields {
  const nlohmann::json& j;
  const std::string& where;

  [[noreturn]] void fail(const std::string& what) const { throw Error(where + ": config: lseg." + what); }
  const nlohmann::json& at(const char* key) const {
    const auto it = j.find(key);
    if (it == j.end()) fail(std::string(key) + " is missing");
    return *it;
  }
  int64_t integer(const char* key, int64_t min = 1) const {
    const nlohmann::json& v = at(key);
    if (!v.is_number_integer()) fail(std::string(key) + " is not an integer");
    const int64_t x = v.get<int64_t>();
    if (x < min) fail(std::string(key) + " = " + std::to_string(x) + " is out of range");
    return x;
  }
  double number(const char* key) const {
    const nlohmann::json& v = at(key);
    if (!v.is_number() || !(v.get<double>() > 0.0)) fail(std::string(key) + " is not a positive number");
    return v.get<double>();
  }
  std::string string(const char* key) const {
    const nlohmann::json& v = at(key);
    if (!v.is_string()) fail(std::string(key) + " is not a string");
    return v.get<std::string>();
  }
  std::array<int64_t, 4> four(const char* key, int64_t min) const {
    const nlohmann::json& v = at(key);
    if (!v.is_array() || v.size() != 4) fail(std::string(key) + " is not a list of 4 integers");
    std::array<int64_t, 4> out{};
    for (size_t i = 0; i < 4; ++i) {
      if (!v[i].is_number_integer() || v[i].get<int64_t>() < min)
        fail(std::string(key) + " is not a list of 4 integers >= " + std::to_string(min));
      out[i] = v[i].get<int64_t>();
    }
    return out;
  }
};

}  // namespace

int64_t LSegConfig::mlpHidden() const { return std::llround(static_cast<double>(width) * mlpRatio); }
int64_t LSegConfig::lastHook() const { return *std::max_element(hooks.begin(), hooks.end()); }

LSegConfig LSegConfig::fromJson(const nlohmann::json& config, const std::string& where) {
  const auto it = config.find("lseg");
  if (it == config.end() || !it->is_object()) throw Error(where + ": config: no 'lseg' object");
  const Fields f{*it, where};
  LSegConfig c;
  c.width = f.integer("width");
  c.depth = f.integer("depth");
  c.numHeads = f.integer("num_heads");
  c.patchSize = f.integer("patch_size");
  c.pretrainImgSize = f.integer("pretrain_img_size");
  c.mlpRatio = f.number("mlp_ratio");
  c.lnEps = f.number("ln_eps");
  c.hooks = f.four("hooks", 0);
  c.reassemble = f.four("reassemble", 1);
  c.features = f.integer("features");
  c.featureDim = f.integer("feature_dim");
  c.inputNorm = f.string("input_norm");
  if (it->contains("readout") && f.string("readout") != "project")
    f.fail("readout '" + f.string("readout") + "' is not implemented (only 'project', LSeg's)");
  if (c.inputNorm != "none" && c.inputNorm != "lseg") f.fail("input_norm '" + c.inputNorm + "' is not none or lseg");
  // The reassemble strides (x4, x2, x1, /2 of the token grid) give H/4 .. H/32 only for 16.
  if (c.patchSize != 16) f.fail("patch_size " + std::to_string(c.patchSize) + " is not implemented (only 16)");
  if (c.width % c.numHeads != 0 || c.headDim() % 4 != 0)
    f.fail("width " + std::to_string(c.width) + " / num_heads " + std::to_string(c.numHeads) +
           " is not a head width that is a multiple of 4");
  if (c.pretrainImgSize % c.patchSize != 0) f.fail("pretrain_img_size is not a multiple of patch_size");
  for (int64_t h : c.hooks)
    if (h >= c.depth) f.fail("hooks: block " + std::to_string(h) + " is beyond depth " + std::to_string(c.depth));
  return c;
}

LSegEncoder::LSegEncoder(Engine& engine, WeightSet& weights, const SparConfig& config)
    : LSegEncoder(engine, weights, LSegConfig::fromJson(config.raw, "LSeg")) {}

LSegEncoder::LSegEncoder(Engine& engine, WeightSet& weights, const LSegConfig& config)
    : engine_(engine), config_(config), options_(timmOptions(config)) {
  loadWeights(weights);
}

void LSegEncoder::loadWeights(WeightSet& weights) {
  const LSegConfig& c = config_;
  const int64_t W = c.width, p = c.patchSize, g = c.pretrainGrid(), f = c.features;
  // Convolution kernels, patchify and copy2d read f32 only (an fp16 matrix is converted on
  // upload); linear weights keep the dtype the set gives them.
  const auto f32 = [&](const std::string& name, const Shape& shape) {
    return weights.require(kPrefix + name, shape, DType::F32);
  };
  const auto any = [&](const std::string& name, const Shape& shape) { return weights.require(kPrefix + name, shape); };
  // A 3x3 convolution kernel: f32, or quantized where the file or the q8 / q4 rule has it so
  // (conv2d dequantizes it; it arrives as the matrix [Cout, Cin*9]).
  const auto convKernel = [&](const std::string& name, const Shape& shape) {
    return isQuantized(weights.uploadType(kPrefix + name)) ? any(name, shape) : f32(name, shape);
  };

  // The patch-embedding conv [W, 3, p, p] is a batch of W "images" 3 x p x p: patchify turns
  // it into [W, p*p*3] in the (ph pw c) order of the image patches, so the embedding is one GEMM
  // (as in model/dino_v3.cpp, where this beat conv2d's 16x16 stride-16 kernel 20x).
  const Tensor conv = f32("pretrained.model.patch_embed.proj.weight", {W, 3, p, p});
  patchBias_ = any("pretrained.model.patch_embed.proj.bias", {W});
  cls_ = f32("pretrained.model.cls_token", {1, 1, W});
  const Tensor pos = f32("pretrained.model.pos_embed", {1, 1 + g * g, W});
  patchWeight_ = engine_.tensor({W, 1, p * p * 3});
  posCls_ = engine_.tensor({1, W});
  posGrid_ = engine_.tensor({1, W, g, g});
  Recorder rec(engine_, /*profile=*/true);  // setup dispatches: their builds are counted too
  patchify(rec, conv, patchWeight_, static_cast<int>(p));
  slice(rec, pos.reshape({1 + g * g, W}), 0, 0, 1, posCls_);
  // The grid's tokens [g*g, W] as a channel-major image [1, W, g, g], what resize reads
  // (unpatchify with patch 1 is exactly that transpose).
  unpatchify(rec, pos.view(W, {1, g * g, W}), posGrid_, 1);

  blocks_.reserve(static_cast<size_t>(c.lastHook() + 1));
  for (int64_t i = 0; i <= c.lastHook(); ++i)
    blocks_.emplace_back(engine_, options_, blockWeights(weights, i, W, options_.hidden()));

  for (int k = 0; k < 4; ++k) {
    const int64_t r = c.reassemble[size_t(k)];
    const std::string a = "pretrained.act_postprocess" + std::to_string(k + 1) + ".";
    Hook& h = hooks_[size_t(k)];
    // project.0 acts on cat(patch, cls): its first W columns meet the patch token, the last W
    // the cls token. Split once, the cls half costs one row per view instead of one per token
    // and the concatenated [V, n, 2W] never exists.
    const Tensor read = f32(a + "0.project.0.weight", {W, 2 * W});
    h.readPatchW = engine_.tensor({W, W});
    h.readClsW = engine_.tensor({W, W});
    sliceColumns(rec, read, 0, W, h.readPatchW);
    sliceColumns(rec, read, W, W, h.readClsW);
    h.readB = any(a + "0.project.0.bias", {W});
    // The 1x1 conv runs on token rows, before the transpose to channel-major.
    h.projW = any(a + "3.weight", {r, W, 1, 1}).reshape({r, W});
    h.projB = any(a + "3.bias", {r});
    const HookTail& t = kTails[k];
    if (t.kind != Tail::None) {
      h.tailW = t.kind == Tail::Conv ? convKernel(a + "4.weight", {r, r, t.kernel, t.kernel})
                                      : f32(a + "4.weight", {r, r, t.kernel, t.kernel});
      h.tailB = f32(a + "4.bias", {r});
    }
    h.rnW = convKernel("scratch.layer" + std::to_string(k + 1) + "_rn.weight", {f, r, 3, 3});
  }
  for (int k = 0; k < 4; ++k) {
    const std::string rn = "scratch.refinenet" + std::to_string(k + 1) + ".";
    Fusion& fz = fusion_[size_t(k)];
    const auto unit = [&](int u) {
      const std::string b = rn + "resConfUnit" + std::to_string(u) + ".";
      return ResidualUnit{convKernel(b + "conv1.weight", {f, f, 3, 3}), f32(b + "conv1.bias", {f}),
                          convKernel(b + "conv2.weight", {f, f, 3, 3}), f32(b + "conv2.bias", {f})};
    };
    if (k < 3) fz.rcu1 = unit(1);  // refinenet4 has a single input (the converter drops its unit 1)
    fz.rcu2 = unit(2);
    fz.outW = f32(rn + "out_conv.weight", {f, f, 1, 1});
    fz.outB = f32(rn + "out_conv.bias", {f});
  }
  headW_ = f32("scratch.head1.weight", {c.featureDim, f, 1, 1});
  headB_ = f32("scratch.head1.bias", {c.featureDim});
  rec.run();
  patchWeight_ = patchWeight_.reshape({W, p * p * 3});
}

const Tensor& LSegEncoder::positions(int64_t gh, int64_t gw) {
  const auto it = positions_.find({gh, gw});
  if (it != positions_.end()) return it->second;
  const int64_t W = config_.width, n = gh * gw;
  const Tensor table = engine_.tensor({1 + n, W});
  const Tensor resized = engine_.tensor({1, W, gh, gw});
  Recorder rec(engine_, /*profile=*/true);  // setup dispatches: their builds are counted too
  copy2d(rec, posCls_, W, 0, table, W, 0, 1, W);  // the cls position is not resized
  resizeBilinear(rec, posGrid_, resized, /*alignCorners=*/false);
  patchify(rec, resized, table.view(W, {1, n, W}), 1);  // back to token-major rows
  rec.run();
  return positions_.emplace(std::make_pair(gh, gw), table).first->second;
}

LSegEncoder::Buffers& LSegEncoder::buffers(int64_t views, int64_t height, int64_t width) {
  Buffers& b = buffers_;
  if (b.views == views && b.height == height && b.width == width) return b;
  b = Buffers{};  // release the old size's memory before allocating the new one
  const LSegConfig& c = config_;
  const int64_t V = views, W = c.width, p = c.patchSize, f = c.features;
  const int64_t gh = height / p, gw = width / p, n = gh * gw;
  const int64_t rMax = *std::max_element(c.reassemble.begin(), c.reassemble.end());
  if (c.inputNorm != "none") b.normalized = engine_.tensor({V, 3, height, width});
  b.patches = engine_.tensor({V, n, p * p * 3});
  b.embedded = engine_.tensor({V, n, W});
  b.prefix = engine_.tensor({V, 1, W});
  b.x = engine_.tensor({V, 1 + n, W});
  b.clsRows = engine_.tensor({V, W});
  b.clsTerm = engine_.tensor({V, W});
  b.readout = engine_.tensor({V, n, W});
  b.projected = engine_.tensor({V * n * rMax});
  b.grid = engine_.tensor({V * n * rMax});
  int64_t tail = 1;
  for (int k = 0; k < 4; ++k)
    if (kTails[k].kind != Tail::None)
      tail = std::max(tail, V * c.reassemble[size_t(k)] * (gh * kTails[k].up / kTails[k].down) *
                                (gw * kTails[k].up / kTails[k].down));
  b.tail = engine_.tensor({tail});
  for (int k = 0; k < 4; ++k) {
    const HookTail& t = kTails[k];
    b.layers[size_t(k)] = engine_.tensor({V, f, gh * t.up / t.down, gw * t.up / t.down});
  }
  // The largest fusion level is l1's (4 gh x 4 gw); scratchB also holds head1's output there.
  const int64_t level1 = V * 16 * n;
  b.up = engine_.tensor({level1 * f});
  b.scratchA = engine_.tensor({level1 * f});
  b.scratchB = engine_.tensor({level1 * std::max(f, c.featureDim)});
  // The cls token is the same for every call: repeat it per view once.
  Recorder rec(engine_, /*profile=*/true);  // setup dispatches: their builds are counted too
  concat(rec, std::vector<Tensor>(static_cast<size_t>(V), cls_), b.prefix, 0);
  rec.run();
  b.views = views;
  b.height = height;
  b.width = width;
  return b;
}

int64_t LSegEncoder::ownFloats(const LSegConfig& c, int64_t views, int64_t height, int64_t width) {
  const int64_t V = views, W = c.width, p = c.patchSize, f = c.features, g = c.pretrainGrid();
  const int64_t gh = height / p, gw = width / p, n = gh * gw;
  const int64_t rMax = *std::max_element(c.reassemble.begin(), c.reassemble.end());
  // construction: patchWeight_, posCls_, posGrid_, and each hook's readPatchW / readClsW
  int64_t floats = W * p * p * 3 + W + W * g * g + 4 * 2 * W * W;
  floats += (1 + n) * W + W * n;  // positions(): the table and the resized grid it is made from
  // buffers(): the same shapes
  if (c.inputNorm != "none") floats += V * 3 * height * width;
  floats += V * n * p * p * 3 + V * n * W + V * W + V * (1 + n) * W + 2 * V * W + V * n * W + 2 * V * n * rMax;
  int64_t tail = 1;
  for (int k = 0; k < 4; ++k)
    if (kTails[k].kind != Tail::None)
      tail = std::max(tail, V * c.reassemble[size_t(k)] * (gh * kTails[k].up / kTails[k].down) *
                                (gw * kTails[k].up / kTails[k].down));
  floats += tail;
  for (int k = 0; k < 4; ++k) floats += V * f * (gh * kTails[k].up / kTails[k].down) * (gw * kTails[k].up / kTails[k].down);
  floats += 2 * V * 16 * n * f + V * 16 * n * std::max(f, c.featureDim);
  return floats;
}

// Hook k's residual stream (b.x) -> readout -> 1x1 conv -> channel-major -> tail -> layerN_rn.
void LSegEncoder::reassemble(Recorder& rec, Buffers& b, int k, int64_t gh, int64_t gw) {
  const Hook& h = hooks_[size_t(k)];
  const HookTail& t = kTails[k];
  const int64_t V = b.views, W = config_.width, n = gh * gw, T = 1 + n, r = config_.reassemble[size_t(k)];

  // readout "project": GELU(Wp patch + Wc cls + b), the cls term once per view as the bias
  // of that view's GEMM.
  copy2d(rec, b.x, T * W, 0, b.clsRows, W, 0, V, W);
  linear(rec, b.clsRows, h.readClsW, h.readB, b.clsTerm);
  for (int64_t v = 0; v < V; ++v)
    linear(rec, b.x.view((v * T + 1) * W, {n, W}), h.readPatchW, b.clsTerm.view(v * W, {W}),
           b.readout.view(v * n * W, {n, W}), Activation::Gelu);

  const Tensor projected = b.projected.view(0, {V, n, r});
  linear(rec, b.readout.reshape({V * n, W}), h.projW, h.projB, projected.reshape({V * n, r}));
  const Tensor grid = b.grid.view(0, {V, r, gh, gw});
  unpatchify(rec, projected, grid, 1);  // [V, n, r] -> [V, r, gh, gw]

  Tensor src = grid;
  const Shape tailShape{V, r, gh * t.up / t.down, gw * t.up / t.down};
  if (t.kind == Tail::ConvT) {
    src = b.tail.view(0, tailShape);
    convTranspose2d(rec, grid, h.tailW, h.tailB, src);
  } else if (t.kind == Tail::Conv) {
    src = b.tail.view(0, tailShape);
    conv2d(rec, grid, h.tailW, h.tailB, src, {.stride = 2, .padY = 1, .padX = 1, .kernelH = 3, .kernelW = 3});
  }
  conv2d(rec, src, h.rnW, Tensor(), b.layers[size_t(k)], {.stride = 1, .padY = 1, .padX = 1, .kernelH = 3, .kernelW = 3});
}

// x += conv2(relu(conv1(relu(x)))), in place; the inner ReLU is fused into conv1.
void LSegEncoder::residualUnit(Recorder& rec, const ResidualUnit& u, const Tensor& x, Buffers& b) {
  const Tensor a = b.scratchA.view(0, x.shape()), c = b.scratchB.view(0, x.shape());
  unary(rec, UnaryOp::Relu, x, a);
  conv2d(rec, a, u.conv1W, u.conv1B, c,
         {.stride = 1, .padY = 1, .padX = 1, .act = Activation::Relu, .kernelH = 3, .kernelW = 3});
  conv2d(rec, c, u.conv2W, u.conv2B, a, {.stride = 1, .padY = 1, .padX = 1, .kernelH = 3, .kernelW = 3});
  add(rec, x, a, x);
}

// refinenet4 .. refinenet1 and head1. Each level's 1x1 out_conv (and head1 after refinenet1)
// runs before the x2 upsampling rather than after it: bilinear interpolation's weights sum to
// 1, so a 1x1 conv with bias commutes with it exactly (up to rounding), at a quarter of the
// multiply-adds.
void LSegEncoder::fuse(Recorder& rec, Buffers& b, const Tensor& features) {
  const int64_t V = b.views, f = config_.features;
  Tensor up;  // the previous level's output, at this level's size
  for (int k = 3; k >= 0; --k) {
    const Fusion& fz = fusion_[size_t(k)];
    const Tensor& l = b.layers[size_t(k)];
    const int64_t h = l.dim(2), w = l.dim(3);
    if (up.defined()) {
      residualUnit(rec, fz.rcu1, l, b);
      add(rec, l, up, l);
    }
    residualUnit(rec, fz.rcu2, l, b);
    const Tensor out = b.scratchA.view(0, {V, f, h, w});
    conv2d(rec, l, fz.outW, fz.outB, out);
    if (k > 0) {
      up = b.up.view(0, {V, f, 2 * h, 2 * w});
      resizeBilinear(rec, out, up, /*alignCorners=*/true);
    } else {
      const Tensor head = b.scratchB.view(0, {V, config_.featureDim, h, w});
      conv2d(rec, out, headW_, headB_, head);
      resizeBilinear(rec, head, features, /*alignCorners=*/true);
    }
  }
}

void LSegEncoder::forward(Recorder& rec, const Tensor& images, const Tensor& features, TransformerWorkspace& ws) {
  const LSegConfig& c = config_;
  if (images.rank() != 4 || images.dim(1) != 3 || images.dtype() != DType::F32)
    throw Error("LSeg: images must be f32 [V, 3, H, W], got " + images.describe());
  const int64_t V = images.dim(0), H = images.dim(2), W = images.dim(3);
  if (H < kSizeMultiple || W < kSizeMultiple || H % kSizeMultiple != 0 || W % kSizeMultiple != 0)
    throw Error("LSeg: image size " + std::to_string(H) + "x" + std::to_string(W) +
                " is not a positive multiple of 32 (the 4th hook's stride-2 conv)");
  const Shape want{V, c.featureDim, H / 2, W / 2};
  if (features.shape() != want || features.dtype() != DType::F32)
    throw Error("LSeg: features must be f32 " + shapeString(want) + ", got " + features.describe());
  if (V == 0) return;
  const int64_t p = c.patchSize, gh = H / p, gw = W / p, n = gh * gw;

  Buffers& b = buffers(V, H, W);
  const Tensor& pos = positions(gh, gw);
  ws.reserve(engine_, V * (1 + n), options_);

  Tensor in = images;
  if (c.inputNorm == "lseg") {
    scale(rec, images, b.normalized, 2.0f, -1.0f);  // (x - 0.5) / 0.5, the same rounding
    in = b.normalized;
  }
  patchify(rec, in, b.patches, static_cast<int>(p));
  linear(rec, b.patches, patchWeight_, patchBias_, b.embedded);
  concat(rec, {b.prefix, b.embedded}, b.x, 1);
  add(rec, b.x, pos, b.x);

  for (int64_t i = 0; i <= c.lastHook(); ++i) {
    blocks_[size_t(i)].forward(rec, b.x, ws);
    for (int k = 0; k < 4; ++k)
      if (c.hooks[size_t(k)] == i) reassemble(rec, b, k, gh, gw);
  }
  fuse(rec, b, features);
}

double LSegEncoder::flops(int64_t views, int64_t height, int64_t width) const {
  const LSegConfig& c = config_;
  const double V = double(views), W = double(c.width), f = double(c.features), p = double(c.patchSize);
  const double gh = double(height) / p, gw = double(width) / p, n = gh * gw, T = 1 + n;
  double mac = V * n * 3 * p * p * W;  // patch embedding
  const double perBlock = V * T * (3 * W * W + W * W + 2 * W * double(c.mlpHidden())) + 2 * V * T * T * W;
  mac += double(c.lastHook() + 1) * perBlock;
  for (int k = 0; k < 4; ++k) {
    const double r = double(c.reassemble[size_t(k)]);
    const HookTail& t = kTails[k];
    const double pixels = n * t.up * t.up / (t.down * t.down);
    mac += V * W * W + V * n * W * W + V * n * W * r;  // readout, 1x1 conv
    if (t.kind != Tail::None) mac += V * pixels * r * r * (t.kind == Tail::ConvT ? 1 : 9);
    mac += V * pixels * r * f * 9;  // layerN_rn
    const double units = k == 3 ? 1 : 2;
    mac += V * pixels * (units * 2 * f * f * 9 + f * f);  // residual units, out_conv
    if (k == 0) mac += V * pixels * f * double(c.featureDim);  // head1
  }
  return 2 * mac;
}

}  // namespace spar
