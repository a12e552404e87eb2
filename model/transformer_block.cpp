#include "model/transformer_block.h"

#include <algorithm>
#include <vector>

#include "spar/error.h"
#include "engine/ops/attention.h"
#include "engine/ops/binary.h"
#include "engine/ops/copy2d.h"
#include "engine/ops/linear.h"
#include "engine/ops/norm.h"
#include "engine/ops/row_padding.h"

namespace spar {
namespace {

const char* kWhat = "transformer block";

std::string withDot(const std::string& prefix) {
  return prefix.empty() || prefix.back() == '.' ? prefix : prefix + ".";
}

Tensor lookup(const WeightLookup& weights, const std::string& prefix, const std::string& name, const Shape& shape,
              bool needF32) {
  const std::string key = prefix + name;
  Tensor t = weights(key);
  if (!t.defined()) throw Error(std::string(kWhat) + ": missing weight " + key);
  if (t.shape() != shape)
    throw Error(std::string(kWhat) + ": " + key + " is " + t.describe() + ", expected " + shapeString(shape));
  if (t.dtype() == DType::I32 || (needF32 && t.dtype() != DType::F32))
    throw Error(std::string(kWhat) + ": " + key + " is " + t.describe() + ", expected " + (needF32 ? "f32" : "f32 or f16"));
  return t;
}

// A weight the lookup stored padded to `shape` (undefined where it could not pad it).
Tensor paddedWeight(const WeightLookup& weights, const std::string& key, const Shape& shape) {
  Tensor t = weights.padded(key, shape);
  if (t.defined() && (t.shape() != shape || (t.dtype() != DType::F32 && t.dtype() != DType::F16)))
    throw Error(std::string(kWhat) + ": " + key + " padded is " + t.describe() + ", expected f32 or f16 " +
                shapeString(shape));
  return t;
}

}  // namespace

TransformerBlockOptions TransformerBlockOptions::spar(int64_t dim, int64_t headDim) {
  TransformerBlockOptions o;
  o.dim = dim;
  o.headDim = headDim;
  return o;
}

TransformerBlockOptions TransformerBlockOptions::clipText(int64_t dim, int64_t headDim) {
  TransformerBlockOptions o = spar(dim, headDim);
  o.lnBias = o.qkvBias = o.fcBias = o.mlpBias = true;
  o.qkNorm = false;
  o.causal = true;
  o.activation = Activation::QuickGelu;
  return o;
}

TransformerBlockOptions TransformerBlockOptions::dinov3(int64_t dim, int64_t headDim) {
  TransformerBlockOptions o = spar(dim, headDim);
  o.lnBias = o.qkvBias = o.fcBias = o.mlpBias = true;
  o.qkNorm = false;
  o.layerScale = true;
  o.maskKBias = true;
  return o;
}

// ---------------------------------------------------------------------------------------------
// Workspace

void TransformerWorkspace::reserve(Engine& engine, int64_t tokens, int64_t dim, int64_t hidden) {
  if (tokens < 0 || dim <= 0 || hidden <= 0)
    throw Error("transformer workspace: bad request (" + std::to_string(tokens) + " tokens, D " + std::to_string(dim) +
                ", hidden " + std::to_string(hidden) + ")");
  const int64_t rows = std::max<int64_t>(tokens, 1);
  // the hidden row as blocks on this device lay it out (engine/ops/row_padding.h)
  const int64_t narrow = rows * dim, wide = rows * std::max(3 * dim, ops::unaliasedRow(engine.plan(), hidden));
  bool grew = false;
  if (!norm_.defined() || norm_.numel() < narrow) {
    norm_ = Tensor();  // release before allocating the larger one
    norm_ = engine.tensor({narrow});
    attn_ = Tensor();
    attn_ = engine.tensor({narrow});
    grew = true;
  }
  if (!big_.defined() || big_.numel() < wide) {
    big_ = Tensor();
    big_ = engine.tensor({wide});
    grew = true;
  }
  if (grew) ++allocations_;
}

Tensor TransformerWorkspace::view(const Tensor& t, int64_t elems, const Shape& shape, const char* what) const {
  if (!t.defined() || t.numel() < elems)
    throw Error(std::string("transformer workspace: too small for ") + what + " " + shapeString(shape) +
                " (call reserve() first)");
  return t.view(0, shape);
}

Tensor TransformerWorkspace::norm(int64_t b, int64_t n, int64_t d) const { return view(norm_, b * n * d, {b, n, d}, "norm"); }
Tensor TransformerWorkspace::attn(int64_t b, int64_t n, int64_t d) const { return view(attn_, b * n * d, {b, n, d}, "attn"); }
Tensor TransformerWorkspace::qkv(int64_t b, int64_t n, int64_t d) const {
  return view(big_, b * n * 3 * d, {b, n, 3 * d}, "qkv");
}
Tensor TransformerWorkspace::hidden(int64_t b, int64_t n, int64_t h) const {
  return view(big_, b * n * h, {b, n, h}, "hidden");
}

size_t TransformerWorkspace::bytes() const {
  size_t s = 0;
  for (const Tensor* t : {&norm_, &attn_, &big_})
    if (t->defined()) s += t->bytes();
  return s;
}

// ---------------------------------------------------------------------------------------------
// Block

std::vector<std::string> TransformerBlock::weightNames(const TransformerBlockOptions& o) {
  std::vector<std::string> n = {"norm1.weight"};
  if (o.lnBias) n.push_back("norm1.bias");
  n.push_back("attn.to_qkv.weight");
  if (o.qkvBias) n.push_back("attn.to_qkv.bias");
  if (o.qkNorm) {
    n.push_back("attn.q_norm.weight");
    n.push_back("attn.k_norm.weight");
  }
  n.push_back("attn.fc.weight");
  if (o.fcBias) n.push_back("attn.fc.bias");
  n.push_back("norm2.weight");
  if (o.lnBias) n.push_back("norm2.bias");
  n.push_back("mlp.mlp.0.weight");
  if (o.mlpBias) n.push_back("mlp.mlp.0.bias");
  n.push_back("mlp.mlp.2.weight");
  if (o.mlpBias) n.push_back("mlp.mlp.2.bias");
  if (o.layerScale) {
    n.push_back("ls1.gamma");
    n.push_back("ls2.gamma");
  }
  return n;
}

TransformerBlock::TransformerBlock(Engine& engine, const TransformerBlockOptions& options, const WeightLookup& weights,
                                   const std::string& prefix0)
    : o_(options) {
  const int64_t D = o_.dim, dh = o_.headDim, H = o_.hidden();
  if (D <= 0 || dh <= 0 || D % dh != 0 || dh % 4 != 0 || D % 4 != 0)
    throw Error(std::string(kWhat) + ": D " + std::to_string(D) + " must be a multiple of the head dim " +
                std::to_string(dh) + ", itself a positive multiple of 4");
  if (o_.maskKBias && !o_.qkvBias) throw Error(std::string(kWhat) + ": maskKBias needs qkvBias");
  if (!weights) throw Error(std::string(kWhat) + ": no weight lookup");
  const std::string p = withDot(prefix0);

  norm1W_ = lookup(weights, p, "norm1.weight", {D}, true);
  norm2W_ = lookup(weights, p, "norm2.weight", {D}, true);
  if (o_.lnBias) {
    norm1B_ = lookup(weights, p, "norm1.bias", {D}, true);
    norm2B_ = lookup(weights, p, "norm2.bias", {D}, true);
  }
  qkvW_ = lookup(weights, p, "attn.to_qkv.weight", {3 * D, D}, false);
  if (o_.qkvBias) qkvB_ = lookup(weights, p, "attn.to_qkv.bias", {3 * D}, o_.maskKBias);
  if (o_.qkNorm) {
    // [q_norm; k_norm] as one [2, dh] weight: the q and k heads normalized in one dispatch.
    qkNormW_ = engine.tensor({2, dh});
    Recorder rec(engine, /*profile=*/true);  // a setup dispatch: its build is counted too
    copy2d(rec, lookup(weights, p, "attn.q_norm.weight", {dh}, true), dh, 0, qkNormW_, dh, 0, 1, dh);
    copy2d(rec, lookup(weights, p, "attn.k_norm.weight", {dh}, true), dh, 0, qkNormW_.view(dh, {1, dh}), dh, 0, 1, dh);
    rec.run();
  }
  fcW_ = lookup(weights, p, "attn.fc.weight", {D, D}, false);
  if (o_.fcBias) fcB_ = lookup(weights, p, "attn.fc.bias", {D}, false);
  // The hidden row wider by zeros where the plan pads aliased rows: mlp.0 gains zero rows (and
  // bias entries), so the hidden's extra columns hold act(0), and mlp.2 zero columns that
  // multiply them: the same sums, on rows the L1 cache does not alias.
  hiddenRow_ = H;
  const int64_t wide = ops::unaliasedRow(engine.plan(), H);
  if (wide != H && weights.padded) {
    mlp2W_ = paddedWeight(weights, p + "mlp.mlp.2.weight", {D, wide});
    if (mlp2W_.defined()) {
      mlp0W_ = paddedWeight(weights, p + "mlp.mlp.0.weight", {wide, D});
      if (o_.mlpBias) mlp0B_ = paddedWeight(weights, p + "mlp.mlp.0.bias", {wide});
      if (!mlp0W_.defined() || (o_.mlpBias && !mlp0B_.defined()))
        throw Error(std::string(kWhat) + ": " + p + "mlp.mlp.2.weight could be padded and mlp.mlp.0 not");
      hiddenRow_ = wide;
    }
  }
  if (hiddenRow_ == H) {
    mlp0W_ = lookup(weights, p, "mlp.mlp.0.weight", {H, D}, false);
    mlp2W_ = lookup(weights, p, "mlp.mlp.2.weight", {D, H}, false);
    if (o_.mlpBias) mlp0B_ = lookup(weights, p, "mlp.mlp.0.bias", {H}, false);
  }
  if (o_.mlpBias) mlp2B_ = lookup(weights, p, "mlp.mlp.2.bias", {D}, false);
  if (o_.layerScale) {
    // x += gamma * (h W^T + b) in the GEMM's epilogue: the gammas ride in the bias binding.
    fcB_ = layerScaleEpilogue(engine, fcB_, lookup(weights, p, "ls1.gamma", {D}, true));
    mlp2B_ = layerScaleEpilogue(engine, mlp2B_, lookup(weights, p, "ls2.gamma", {D}, true));
  }

  if (o_.maskKBias) {
    // DINOv3 multiplies the k third of the qkv bias by 0: bias' = bias * [1..1 0..0 1..1],
    // prepared once here on the device (the mask is a constant, not a computed value).
    std::vector<float> keep(static_cast<size_t>(3 * D), 1.0f);
    std::fill(keep.begin() + D, keep.begin() + 2 * D, 0.0f);
    const Tensor mask = engine.fromFloats({3 * D}, keep);
    const Tensor masked = engine.tensor({3 * D});
    Recorder rec(engine, /*profile=*/true);  // a setup dispatch: its build is counted too
    mul(rec, qkvB_, mask, masked);
    rec.run();
    qkvB_ = masked;
  }
}

void TransformerBlock::forward(Recorder& rec, const Tensor& x, const TransformerWorkspace& ws,
                               const BlockRope* rope) const {
  const int64_t D = o_.dim, H = hiddenRow_, heads = o_.heads(), dh = o_.headDim;
  if (x.rank() != 3 || x.dim(2) != D || x.dtype() != DType::F32)
    throw Error(std::string(kWhat) + ": x must be f32 [B, N, " + std::to_string(D) + "], got " + x.describe());
  const int64_t B = x.dim(0), N = x.dim(1);
  if (B * N == 0) return;
  const TransformerBlockCount count(rec);
  const Tensor norm = ws.norm(B, N, D), attn = ws.attn(B, N, D), qkv = ws.qkv(B, N, D), hidden = ws.hidden(B, N, H);

  // Attention branch: qkv = to_qkv(norm1(x)); heads read straight out of the fused qkv tensor,
  // q and k RMS-normed per head (q_norm, k_norm) and rotated (RoPE) as the kernel reads them.
  layerNorm(rec, x, norm1W_, norm1B_, norm, o_.lnEps);
  linear(rec, norm, qkvW_, qkvB_, qkv);
  QkPrep prep;
  if (o_.qkNorm) prep.normWeight = qkNormW_, prep.normEps = o_.qkNormEps;
  if (rope) prep.ropeSin = rope->sin, prep.ropeCos = rope->cos, prep.ropePrefix = rope->prefix;
  // a block with fp16 weights (--precision fp16) may round q, k, v to fp16 for cooperative matrices
  attention(rec, {qkv, 0}, {qkv, D}, {qkv, 2 * D}, {attn, 0}, int(heads), int(dh), o_.causal, 0.0f,
            qkvW_.dtype() == DType::F16, prep);
  // x += fc(attn) (times the layer scale where the block has one): the residual add, and the
  // scale, fused into the GEMM
  linear(rec, attn, fcW_, fcB_, x, Activation::None, /*accumulate=*/true);

  // MLP branch: the activation is fused into the first GEMM; hidden reuses qkv's buffer.
  layerNorm(rec, x, norm2W_, norm2B_, norm, o_.lnEps);
  linear(rec, norm, mlp0W_, mlp0B_, hidden, o_.activation);
  linear(rec, hidden, mlp2W_, mlp2B_, x, Activation::None, /*accumulate=*/true);
}

void forwardBlocks(Recorder& rec, const std::vector<TransformerBlock>& blocks, const Tensor& x,
                   const TransformerWorkspace& ws, const BlockRope* rope) {
  for (const TransformerBlock& b : blocks) b.forward(rec, x, ws, rope);
}

}  // namespace spar
