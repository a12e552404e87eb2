// CV-DRP on the engine (model/cv_drp.h).
#include "model/cv_drp.h"

#include <algorithm>
#include <string>
#include <utility>

#include "spar/error.h"
#include "engine/ops/binary.h"
#include "engine/ops/conv2d.h"
#include "engine/ops/conv_transpose2d.h"
#include "engine/ops/copy2d.h"
#include "engine/ops/linear.h"
#include "engine/ops/patchify.h"
#include "engine/ops/unary.h"
#include "model/stack.h"

namespace spar {
namespace {

const std::string kPrefix = "cv_drp.estimator.";
const std::string kDecoder = kPrefix + "dpt_decoder.";
// DPTDecoder's widths are hard-coded in the official code, whatever D is.
constexpr int64_t kProjectChannels = 256;
constexpr int64_t kUpChannels[] = {256, 128, 64, 32};
constexpr int64_t kFinalChannels = 16;
// Three stride-2 up blocks and the final stride-2 transposed conv: x16 per axis.
constexpr int64_t kUpscale = 16;

void fail(const std::string& what) { throw Error("CV-DRP: " + what); }

}  // namespace

std::vector<std::pair<int64_t, int64_t>> cvDrpPairs(int64_t views, CvDrpMode mode) {
  if (views < 1) fail("no views to pair");
  std::vector<std::pair<int64_t, int64_t>> pairs;
  if (mode == CvDrpMode::Input) {
    if (views == 1) return {{0, 0}};
    for (int64_t i = 0; i + 1 < views; ++i) pairs.emplace_back(i, i + 1);
    return pairs;
  }
  for (int64_t i = 0; i < views / 2; ++i) pairs.emplace_back(i, views - 1 - i);
  if (views % 2 == 1) {
    // Official: the middle target would otherwise be in no pair; it joins its predecessor
    // (a single target pairs with itself).
    const int64_t mid = views / 2;
    pairs.emplace_back(mid, std::max<int64_t>(0, mid - 1));
  }
  return pairs;
}

CvDrp::CvDrp(Engine& engine, WeightSet& weights, const SparConfig& config) : engine_(engine), d_(config.d) {
  const int64_t d = d_;
  if (config.patchSize != kUpscale)
    fail("the decoder upsamples by exactly 16, the patch size is " + std::to_string(config.patchSize));
  // CV-DRP's blocks always have QK-norm (official CVDRPFusion), whatever use_qk_norm says.
  blocks_ = loadStack(engine, weights, TransformerBlockOptions::spar(d, config.cvDrpHeadDim()),
                      kPrefix + "transformer_layers", config.cvDrpLayers);

  fuse0W_ = weights.require(kPrefix + "fusion_mlp.net.0.weight", {2 * d, 3 * d});
  fuse0B_ = weights.require(kPrefix + "fusion_mlp.net.0.bias", {2 * d});
  fuse2W_ = weights.require(kPrefix + "fusion_mlp.net.2.weight", {d, 2 * d});
  fuse2B_ = weights.require(kPrefix + "fusion_mlp.net.2.bias", {d});

  // The convolution kernels take f32 only (an fp16 file is converted on upload).
  const auto f32 = [&](const std::string& name, const Shape& shape) {
    return weights.require(kDecoder + name, shape, DType::F32);
  };
  projW_ = f32("project.0.weight", {kProjectChannels, d, 1, 1}).reshape({kProjectChannels, d});
  projB_ = f32("project.0.bias", {kProjectChannels});
  for (int i = 0; i < 3; ++i) {
    const int64_t cin = kUpChannels[i], cout = kUpChannels[i + 1];
    const std::string b = "up_blocks." + std::to_string(i) + ".";
    up_.push_back({f32(b + "0.weight", {cin, cout, 2, 2}), f32(b + "0.bias", {cout}),
                   f32(b + "3.weight", {cout, cout, 3, 3}), f32(b + "3.bias", {cout})});
  }
  finalW_ = f32("final_up.0.weight", {kUpChannels[3], kFinalChannels, 2, 2});
  finalB_ = f32("final_up.0.bias", {kFinalChannels});
  headW_ = f32("head.weight", {1, kFinalChannels, 1, 1});
  headB_ = f32("head.bias", {1});
}

Tensor CvDrp::scratch(Tensor& held, const Shape& shape) {
  const int64_t need = std::max<int64_t>(shapeNumel(shape), 1);
  if (!held.defined() || held.numel() < need) {
    held = Tensor();  // release before allocating the larger one (pending work keeps its copy)
    held = engine_.tensor({need});
    ++allocations_;
  }
  return held.view(0, shape);
}

namespace {
// The ping and pong buffers' sizes for a call: what each holds in turn (forward, then decode),
// the largest of them.
std::pair<int64_t, int64_t> pingPongFloats(int64_t d, int64_t views, int64_t images, int64_t n) {
  int64_t ping = std::max(views * n * 3 * d, images * n * kProjectChannels);
  int64_t pong = std::max(views * n * 2 * d, images * n * kProjectChannels);
  int64_t pixels = n;
  for (int i = 1; i < 4; ++i) {
    pixels *= 4;
    ping = std::max(ping, images * kUpChannels[i] * pixels);  // transposed conv output
    pong = std::max(pong, images * kUpChannels[i] * pixels);  // 3x3 conv output
  }
  ping = std::max(ping, images * kFinalChannels * pixels * 4);
  return {ping, pong};
}
}  // namespace

void CvDrp::planScratch(int64_t views, int64_t images, int64_t n) {
  const auto [ping, pong] = pingPongFloats(d_, views, images, n);
  scratch(pingBuf_, {ping});
  scratch(pongBuf_, {pong});
}

int64_t CvDrp::pairCount(int64_t views, CvDrpMode mode) { return int64_t(cvDrpPairs(views, mode).size()); }

int64_t CvDrp::scratchFloats(int64_t d, int64_t views, int64_t pairs, int64_t n) {
  const int64_t images = 2 * pairs;
  const auto [ping, pong] = pingPongFloats(d, views, images, n);
  // + the pair batch's tokens [P, 2n, D] and its decoder logits [2P, 1, 16gh, 16gw]
  return ping + pong + images * n * d + images * 256 * n;
}

// tokens: [images, n, D] -> out: [images, 1, 16gh, 16gw]. Activations alternate between the
// ping and pong buffers; GELU is fused into every conv.
void CvDrp::decode(Recorder& rec, const Tensor& tokens, int64_t images, int64_t gh, int64_t gw, const Tensor& out) {
  const int64_t n = gh * gw;
  // The 1x1 projection is a linear over token rows; then one transpose to channel-major
  // (unpatchify with patch 1 is exactly [m, n, C] -> [m, C, gh, gw]), on 256 channels rather
  // than D.
  const Tensor projected = scratch(pingBuf_, {images, n, kProjectChannels});
  linear(rec, tokens.reshape({images * n, d_}), projW_, projB_, projected.reshape({images * n, kProjectChannels}),
         Activation::Gelu);
  Tensor x = scratch(pongBuf_, {images, kProjectChannels, gh, gw});
  unpatchify(rec, projected, x, 1);

  int64_t h = gh, w = gw;
  const Conv2dParams conv3x3{.stride = 1, .padY = 1, .padX = 1, .act = Activation::Gelu};
  for (size_t i = 0; i < up_.size(); ++i) {
    const int64_t c = kUpChannels[i + 1];
    h *= 2;
    w *= 2;
    const Tensor up = scratch(pingBuf_, {images, c, h, w});
    convTranspose2d(rec, x, up_[i].upW, up_[i].upB, up, Activation::Gelu);
    x = scratch(pongBuf_, {images, c, h, w});
    conv2d(rec, up, up_[i].convW, up_[i].convB, x, conv3x3);
  }
  const Tensor fin = scratch(pingBuf_, {images, kFinalChannels, 2 * h, 2 * w});
  convTranspose2d(rec, x, finalW_, finalB_, fin, Activation::Gelu);
  conv2d(rec, fin, headW_, headB_, out);
}

void CvDrp::forward(Recorder& rec, const Tensor& dino, const Tensor& img, const Tensor& ray,
                    const std::vector<int64_t>& views, CvDrpMode mode, int64_t gh, int64_t gw, const Tensor& logits,
                    const Tensor& prob, TransformerWorkspace& ws, CvDrpTrace* trace) {
  const int64_t d = d_, n = gh * gw, k = int64_t(views.size());
  if (gh < 1 || gw < 1) fail("bad token grid " + std::to_string(gh) + "x" + std::to_string(gw));
  using Named = std::pair<const Tensor*, const char*>;
  for (const auto& [t, what] : {Named{&dino, "dino"}, Named{&img, "image"}, Named{&ray, "ray"}})
    if (t->rank() != 3 || t->dim(1) != n || t->dim(2) != d || t->dtype() != DType::F32 || t->shape() != dino.shape())
      fail(std::string(what) + " tokens " + t->describe() + " should be f32 [V, " + std::to_string(n) + ", " +
           std::to_string(d) + "] like the others (the DINO width must equal D)");
  if (k < 1) fail("no views given");
  for (size_t i = 0; i < views.size(); ++i)
    if (views[i] < 0 || views[i] >= dino.dim(0) || (i > 0 && views[i] <= views[i - 1]))
      fail("view positions must be increasing and within the " + std::to_string(dino.dim(0)) + " views");
  const int64_t H = kUpscale * gh, W = kUpscale * gw, hw = H * W;
  for (const Tensor* t : {&logits, &prob})
    if (t->shape() != Shape{k, 1, H, W} || t->dtype() != DType::F32)
      fail("output " + t->describe() + " should be f32 " + shapeString({k, 1, H, W}));

  const auto pairs = cvDrpPairs(k, mode);
  const int64_t p = int64_t(pairs.size()), images = 2 * p;
  planScratch(k, images, n);

  // fusion_mlp once per view of the subset: concat(dino, img, ray) gathered view by view.
  const Tensor cat = scratch(pingBuf_, {k * n, 3 * d});
  for (int64_t j = 0; j < k; ++j) {
    const Tensor rows = cat.view(j * n * 3 * d, {n, 3 * d});
    int64_t col = 0;
    for (const Tensor* src : {&dino, &img, &ray}) {
      copy2d(rec, src->view(views[j] * n * d, {n, d}), d, 0, rows, 3 * d, col, n, d);
      col += d;
    }
  }
  const Tensor hidden = scratch(pongBuf_, {k * n, 2 * d});
  linear(rec, cat, fuse0W_, fuse0B_, hidden, Activation::Gelu);
  const Tensor fused = scratch(pingBuf_, {k * n, d});  // cat is dead once hidden is written
  linear(rec, hidden, fuse2W_, fuse2B_, fused);

  // All pairs as one batch [P, 2n, D]: view i's tokens then view j's.
  const Tensor tokens = scratch(tokenBuf_, {p, 2 * n, d});
  for (int64_t q = 0; q < p; ++q)
    for (int side = 0; side < 2; ++side) {
      const int64_t v = side == 0 ? pairs[size_t(q)].first : pairs[size_t(q)].second;
      copy2d(rec, fused.view(v * n * d, {n * d}), n * d, 0, tokens.view((2 * q + side) * n * d, {n * d}), n * d, 0, 1,
             n * d);
    }
  const auto keepCopy = [&](const Tensor& t) {
    const Tensor c = engine_.tensor(t.shape());
    copy2d(rec, t.reshape({t.numel()}), t.numel(), 0, c.reshape({c.numel()}), c.numel(), 0, 1, t.numel());
    return c;
  };
  if (trace) {
    trace->pairs = pairs;
    trace->pairFused = keepCopy(tokens);
  }
  if (!blocks_.empty()) ws.reserve(engine_, p * 2 * n, blocks_[0].options());
  forwardBlocks(rec, blocks_, tokens, ws);
  if (trace) trace->pairTokens = keepCopy(tokens);

  // Decoder over the 2P views of the batch: [2P, n, D] -> [2P, 1, H, W].
  const Tensor pairLogits = scratch(pairLogitBuf_, {images, 1, H, W});
  decode(rec, tokens.reshape({images, n, d}), images, gh, gw, pairLogits);
  if (trace) trace->pairLogits = keepCopy(pairLogits).reshape({p, 2, 1, H, W});

  // Each view's logits: the mean over the pair slots it occupies, before the sigmoid (a view
  // paired with itself counts once).
  std::vector<std::vector<int64_t>> slots(static_cast<size_t>(k));
  for (int64_t q = 0; q < p; ++q) {
    const auto [i, j] = pairs[size_t(q)];
    slots[size_t(i)].push_back(2 * q);
    if (i != j) slots[size_t(j)].push_back(2 * q + 1);
  }
  const auto slot = [&](int64_t s) { return pairLogits.view(s * hw, {hw}); };
  for (int64_t v = 0; v < k; ++v) {
    const std::vector<int64_t>& s = slots[size_t(v)];
    if (s.empty()) fail("view " + std::to_string(v) + " is in no pair");  // cannot happen: cvDrpPairs covers all
    const Tensor out = logits.view(v * hw, {hw});
    if (s.size() == 1) {
      copy2d(rec, slot(s[0]), hw, 0, out, hw, 0, 1, hw);
      continue;
    }
    add(rec, slot(s[0]), slot(s[1]), out);
    for (size_t t = 2; t < s.size(); ++t) add(rec, out, slot(s[t]), out);
    scale(rec, out, out, 1.0f / float(s.size()));
  }
  unary(rec, UnaryOp::Sigmoid, logits, prob);
}

}  // namespace spar
