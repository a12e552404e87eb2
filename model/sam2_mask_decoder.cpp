// SAM2.1's prompt encoder and mask decoder (model/sam2_mask_decoder.h); the glue kernels are
// model/shaders/sam2_decoder.comp.
#include "model/sam2_mask_decoder.h"

#include <cstring>

#include "spar/error.h"
#include "engine/ops/attention.h"
#include "engine/ops/binary.h"
#include "engine/ops/conv2d.h"
#include "engine/ops/conv_transpose2d.h"
#include "engine/ops/copy2d.h"
#include "engine/ops/dispatch_helpers.h"
#include "engine/ops/linear.h"
#include "engine/ops/norm.h"
#include "engine/ops/resize.h"
#include "engine/ops/unary.h"
#include "model/model_shaders.h"
#include "model/sam2_windows.h"

namespace spar {
namespace {

constexpr int64_t kHeads = 8, kMlp = 2048, kMaskTokens = 4;

struct DecoderPush {
  uint32_t total, a, b;
};

void glue(Recorder& rec, const char* variant, const std::vector<Arg>& args, const std::vector<Bind>& binds,
          const DecoderPush& push) {
  Engine& engine = rec.engine();
  registerModelShaders();  // model/shaders/sam2_decoder.comp
  const Kernel& kernel = engine.kernel({variant, binds, sizeof(DecoderPush), {ops::elementLocalX(engine.caps()), 1, 1}});
  const ops::Grid grid =
      ops::linearGrid(engine.caps(), ops::ceilDiv(uint64_t(push.total), uint64_t(ops::elementLocalX(engine.caps()))), variant);
  rec.dispatch(kernel, args, push, grid.x, grid.y, 1, variant);
}

// [H * W, C] -> [1, C, H, W]
void channelsFirst(Recorder& rec, const Tensor& x, const Tensor& y) {
  glue(rec, "sam2_channels_first", {Arg::in(x), Arg::out(y)}, {Bind::Read, Bind::Write},
       {uint32_t(y.numel()), uint32_t(x.dim(0)), uint32_t(x.dim(1))});
}

}  // namespace

void sam2Threshold(Recorder& rec, const Tensor& x, float t, const Tensor& y) {
  if (!x.defined() || !y.defined() || x.numel() != y.numel()) throw Error("sam2Threshold: x and y must have one size");
  ops::requireF32(x, "sam2Threshold", "x");
  ops::requireF32(y, "sam2Threshold", "y");
  uint32_t bits = 0;
  std::memcpy(&bits, &t, sizeof(bits));
  if (y.numel() == 0) return;
  glue(rec, "sam2_threshold", {Arg::in(x), Arg::out(y)}, {Bind::Read, Bind::Write}, {uint32_t(y.numel()), bits, 0});
}

void sam2CountDynamic(Recorder& rec, const Tensor& probs, const Tensor& counts) {
  if (!probs.defined() || probs.rank() != 3) throw Error("sam2CountDynamic: probs must be [V, H, W]");
  ops::requireF32(probs, "sam2CountDynamic", "probs");
  const int64_t V = probs.dim(0), hw = probs.dim(1) * probs.dim(2);
  if (!counts.defined() || counts.dtype() != DType::I32 || counts.numel() != V)
    throw Error("sam2CountDynamic: counts must be i32 [" + std::to_string(V) + "]");
  const std::vector<int32_t> zeros(size_t(V), 0);
  rec.engine().write(counts, zeros.data(), zeros.size() * sizeof(int32_t));
  const int64_t runs = (hw + 63) / 64;
  if (V == 0 || hw == 0) return;
  glue(rec, "sam2_count_dynamic", {Arg::in(probs), Arg::inout(counts)}, {Bind::Read, Bind::ReadWrite},
       {uint32_t(V * runs), uint32_t(hw), uint32_t(runs)});
}

Sam2MaskDecoder::Sam2MaskDecoder(Engine& engine, const Sam2Config& config, WeightLookup weights, std::string prefix)
    : engine_(engine), config_(config), weights_(std::move(weights)), prefix_(std::move(prefix)) {
  const int64_t d = config_.dModel, side = config_.tokenSide() / 4;
  densePe_ = engine_.tensor({side * side, d});
  tokens_ = engine_.tensor({2 + kMaskTokens, d});
  Recorder rec(engine_);
  glue(rec, "sam2_dense_pe", {Arg::in(weight("sam_prompt_encoder.pe_layer.positional_encoding_gaussian_matrix")),
                              Arg::out(densePe_)},
       {Bind::Read, Bind::Write}, {uint32_t(densePe_.numel()), uint32_t(side), uint32_t(d / 2)});
  concat(rec, {weight("sam_mask_decoder.obj_score_token.weight"), weight("sam_mask_decoder.iou_token.weight"),
               weight("sam_mask_decoder.mask_tokens.weight")},
         tokens_, 0);
  rec.run();
}

Tensor Sam2MaskDecoder::weight(const std::string& name) const {
  Tensor t = weights_(prefix_ + name);
  if (!t.defined()) throw Error("SAM2 mask decoder: missing weight " + prefix_ + name);
  return t;
}

Tensor Sam2MaskDecoder::linearOf(Recorder& rec, const std::string& p, const Tensor& x, int64_t out, Activation act) const {
  const Tensor w = weight(p + "weight");
  Shape shape = x.shape();
  shape.back() = out;
  const Tensor y = engine_.tensor(shape);
  linear(rec, x, w.rank() == 4 ? w.reshape({w.dim(0), w.dim(1)}) : w, weight(p + "bias"), y, act);
  return y;
}

Tensor Sam2MaskDecoder::mlp3(Recorder& rec, const std::string& p, const Tensor& x, int64_t out, Activation last) const {
  const int64_t hidden = weight(p + "0.weight").dim(0);
  const Tensor h0 = linearOf(rec, p + "0.", x, hidden, Activation::Relu);
  const Tensor h1 = linearOf(rec, p + "1.", h0, hidden, Activation::Relu);
  return linearOf(rec, p + "2.", h1, out, last);
}

// q/k/v projections to the attention's internal width, 8 heads, the output projection
Tensor Sam2MaskDecoder::attention(Recorder& rec, const std::string& p, const Tensor& q, const Tensor& k,
                                  const Tensor& v) const {
  const int64_t internal = weight(p + "q_proj.weight").dim(0), d = config_.dModel;
  const Tensor qp = linearOf(rec, p + "q_proj.", q, internal), kp = linearOf(rec, p + "k_proj.", k, internal),
               vp = linearOf(rec, p + "v_proj.", v, internal);
  const Tensor a = engine_.tensor({q.dim(0), internal});
  spar::attention(rec, HeadsView{qp, 0}, HeadsView{kp, 0}, HeadsView{vp, 0}, HeadsView{a, 0}, int(kHeads),
                  int(internal / kHeads));
  return linearOf(rec, p + "out_proj.", a, d);
}

// The prompt: +-10 of the view's binary mask, at maskInputSize() a side (256 at 1024; bilinear,
// align_corners=False), and the dense prompt from it (r.prompt, r.dense).
void Sam2MaskDecoder::prompt(Recorder& rec, const Tensor& probs, int64_t view, Sam2MaskResult& r) const {
  const int64_t side = config_.tokenSide() / 4, d = config_.dModel;
  const int64_t kPromptSide = config_.maskInputSize();
  const int64_t H = probs.dim(1), W = probs.dim(2);
  const Tensor binary = engine_.tensor({1, 1, H, W});
  const Tensor viewProbs = engine_.tensor({H, W});
  slice(rec, probs, 0, view, 1, viewProbs.reshape({1, H, W}));
  glue(rec, "sam2_mask_prompt", {Arg::in(viewProbs), Arg::out(binary)}, {Bind::Read, Bind::Write},
       {uint32_t(H * W), 0, 0});
  Tensor prompt = binary;
  if (H != kPromptSide || W != kPromptSide) {
    prompt = engine_.tensor({1, 1, kPromptSide, kPromptSide});
    resizeBilinear(rec, binary, prompt, false);
  }
  r.prompt = prompt.reshape({kPromptSide * kPromptSide});

  // the dense prompt: two k2s2 convs with LayerNorm2d and GELU, then a 1x1 conv
  const std::string ds = "sam_prompt_encoder.mask_downscaling.";
  auto lnGelu = [&](const Tensor& nchw, const std::string& norm) {
    const int64_t c = nchw.dim(1), hw = nchw.dim(2) * nchw.dim(3);
    const Tensor t = engine_.tensor({hw, c});
    sam2ChannelsLast(rec, nchw, t);
    layerNorm(rec, t, weight(norm + "weight"), weight(norm + "bias"), t, 1e-6f);
    activate(rec, Activation::Gelu, t, t);
    return t;
  };
  Conv2dParams k2s2;
  k2s2.stride = 2;
  const Tensor w0 = weight(ds + "0.weight"), w3 = weight(ds + "3.weight");
  const Tensor c1 = engine_.tensor({1, w0.dim(0), kPromptSide / 2, kPromptSide / 2});
  conv2d(rec, prompt, w0, weight(ds + "0.bias"), c1, k2s2);
  const Tensor t1 = lnGelu(c1, ds + "1.");
  const Tensor c1first = engine_.tensor(c1.shape());
  channelsFirst(rec, t1, c1first);
  const Tensor c2 = engine_.tensor({1, w3.dim(0), side, side});
  conv2d(rec, c1first, w3, weight(ds + "3.bias"), c2, k2s2);
  const Tensor t2 = lnGelu(c2, ds + "4.");
  r.dense = linearOf(rec, ds + "6.", t2, d);

}

// The two-way transformer over image_embed + dense, with the dense PE: the queries (the decoder's
// tokens out, r.tokensOut) and the keys it returns.
Tensor Sam2MaskDecoder::twoWay(Recorder& rec, const Sam2ImageFeatures& f, Sam2MaskResult& r) const {
  const int64_t side = config_.tokenSide() / 4, d = config_.dModel;
  const std::string tw = "sam_mask_decoder.transformer.";
  Tensor keys = engine_.tensor({side * side, d});
  add(rec, f.imageEmbed, r.dense, keys);
  Tensor queries = tokens_;
  const Tensor& T0 = tokens_;
  auto plus = [&](const Tensor& a, const Tensor& b) {
    const Tensor s = engine_.tensor(a.shape());
    add(rec, a, b, s);
    return s;
  };
  auto residualNorm = [&](const Tensor& x, const Tensor& delta, const std::string& norm) {
    const Tensor s = plus(x, delta);
    layerNorm(rec, s, weight(norm + "weight"), weight(norm + "bias"), s, 1e-5f);
    return s;
  };
  for (int layer = 0; layer < 2; ++layer) {
    const std::string p = tw + "layers." + std::to_string(layer) + ".";
    if (layer == 0) {  // skip_first_layer_pe: no PE, no residual
      queries = attention(rec, p + "self_attn.", queries, queries, queries);
      layerNorm(rec, queries, weight(p + "norm1.weight"), weight(p + "norm1.bias"), queries, 1e-5f);
    } else {
      const Tensor q = plus(queries, T0);
      queries = residualNorm(queries, attention(rec, p + "self_attn.", q, q, queries), p + "norm1.");
    }
    Tensor q = plus(queries, T0), k = plus(keys, densePe_);
    queries = residualNorm(queries, attention(rec, p + "cross_attn_token_to_image.", q, k, keys), p + "norm2.");
    const Tensor hidden = linearOf(rec, p + "mlp.layers.0.", queries, kMlp, Activation::Relu);
    queries = residualNorm(queries, linearOf(rec, p + "mlp.layers.1.", hidden, d), p + "norm3.");
    q = plus(queries, T0);
    k = plus(keys, densePe_);
    keys = residualNorm(keys, attention(rec, p + "cross_attn_image_to_token.", k, q, queries), p + "norm4.");
  }
  {
    const Tensor q = plus(queries, T0), k = plus(keys, densePe_);
    queries = residualNorm(queries, attention(rec, tw + "final_attn_token_to_image.", q, k, keys), tw + "norm_final_attn.");
  }
  r.tokensOut = queries;

  return keys;
}

// Upscaling: ConvT + feat_s1, LayerNorm2d, GELU; ConvT + feat_s0, GELU (channel-last between) (r.upscaled).
void Sam2MaskDecoder::upscale(Recorder& rec, const Sam2ImageFeatures& f, const Tensor& keys, Sam2MaskResult& r) const {
  const int64_t side = config_.tokenSide() / 4, d = config_.dModel, up = config_.tokenSide();
  const std::string us = "sam_mask_decoder.output_upscaling.";
  const Tensor src = engine_.tensor({1, d, side, side});
  channelsFirst(rec, keys, src);
  const Tensor u1 = engine_.tensor({1, d / 4, 2 * side, 2 * side});
  convTranspose2d(rec, src, weight(us + "0.weight"), weight(us + "0.bias"), u1);
  const Tensor u1t = engine_.tensor({4 * side * side, d / 4});
  sam2ChannelsLast(rec, u1, u1t);
  add(rec, u1t, f.featS1, u1t);
  layerNorm(rec, u1t, weight(us + "1.weight"), weight(us + "1.bias"), u1t, 1e-6f);
  activate(rec, Activation::Gelu, u1t, u1t);
  const Tensor u1first = engine_.tensor(u1.shape());
  channelsFirst(rec, u1t, u1first);
  const Tensor u2 = engine_.tensor({1, d / 8, up, up});
  convTranspose2d(rec, u1first, weight(us + "3.weight"), weight(us + "3.bias"), u2);
  r.upscaled = engine_.tensor({up * up, d / 8});
  sam2ChannelsLast(rec, u2, r.upscaled);
  add(rec, r.upscaled, f.featS0, r.upscaled);
  activate(rec, Activation::Gelu, r.upscaled, r.upscaled);

}

// Hypernetworks of mask tokens 1-3 (token rows 3-5) and the IoU head (row 1): the IoU
// predictions, the chosen mask's logits, and with allMasks every mask's.
void Sam2MaskDecoder::heads(Recorder& rec, Sam2MaskResult& r, bool allMasks) const {
  const int64_t d = config_.dModel, up = config_.tokenSide();
  const Tensor& queries = r.tokensOut;
  const std::string md = "sam_mask_decoder.";
  std::vector<Tensor> hyper;
  for (int m = 1; m < kMaskTokens; ++m) {
    const Tensor row = engine_.tensor({1, d});
    slice(rec, queries, 0, 2 + m, 1, row);
    hyper.push_back(mlp3(rec, md + "output_hypernetworks_mlps." + std::to_string(m) + ".layers.", row, d / 8,
                         Activation::None));
  }
  const Tensor hyperAll = engine_.tensor({kMaskTokens - 1, d / 8});
  concat(rec, hyper, hyperAll, 0);
  const Tensor iouRow = engine_.tensor({1, d});
  slice(rec, queries, 0, 1, 1, iouRow);
  const Tensor iou4 = mlp3(rec, md + "iou_prediction_head.layers.", iouRow, kMaskTokens, Activation::Sigmoid);
  r.iou = engine_.tensor({1, kMaskTokens - 1});
  sliceColumns(rec, iou4, 1, kMaskTokens - 1, r.iou);
  r.chosenLogits = engine_.tensor({up * up});
  glue(rec, "sam2_chosen_mask", {Arg::in(r.upscaled), Arg::out(r.chosenLogits), Arg::in(hyperAll), Arg::in(r.iou)},
       {Bind::Read, Bind::Write, Bind::Read, Bind::Read}, {uint32_t(up * up), 0, uint32_t(d / 8)});
  if (allMasks) {
    r.allLogits = engine_.tensor({up * up, kMaskTokens - 1});
    linear(rec, r.upscaled, hyperAll, Tensor(), r.allLogits);
  }
}

Sam2MaskResult Sam2MaskDecoder::decode(Recorder& rec, const Sam2ImageFeatures& f, const Tensor& probs, int64_t view,
                                       bool allMasks) const {
  const std::string op = "sam2 mask decoder";
  if (!probs.defined() || probs.rank() != 3 || view < 0 || view >= probs.dim(0))
    throw Error(op + ": probs must be [V, H, W] holding view " + std::to_string(view));
  Sam2MaskResult r;
  prompt(rec, probs, view, r);
  const Tensor keys = twoWay(rec, f, r);
  upscale(rec, f, keys, r);
  heads(rec, r, allMasks);
  return r;
}

}  // namespace spar
