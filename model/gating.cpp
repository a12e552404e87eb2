// Token fusion and gating (model/gating.h); kernel model/shaders/token_gate.comp.
#include "model/gating.h"

#include "engine/ops/binary.h"
#include "engine/ops/copy2d.h"
#include "engine/ops/dispatch_helpers.h"
#include "engine/ops/linear.h"
#include "engine/ops/norm.h"
#include "engine/ops/pool.h"
#include "model/sincos_codes.h"
#include "model/model_shaders.h"

namespace spar {
namespace {
struct GatePush {
  uint32_t tokens, dim, perView, mode;
};
}  // namespace

TokenGating::TokenGating(Engine& engine, WeightSet& weights, const SparConfig& config)
    : engine_(engine), config_(config) {
  const int64_t d = config.d;
  lnW_ = weights.require("mlp_fuse.0.weight", {2 * d}, DType::F32);
  w1_ = weights.require("mlp_fuse.1.weight", {d, 2 * d});
  b1_ = weights.require("mlp_fuse.1.bias", {d}, DType::F32);
  w2_ = weights.require("mlp_fuse.3.weight", {d, d});
  b2_ = weights.require("mlp_fuse.3.bias", {d}, DType::F32);
  viewType0_ = weights.require("view_type_embedding.weight", {2, d}, DType::F32).view(0, {d});
  if (config.inputMaskingMode == "soft_with_pe") {
    mask_ = weights.require("mask_token", {1, 1, d}, DType::F32).reshape({d});
  }
}

// The 2D sin-cos code of a token grid, [gh * gw + 1, d], its last row the mask token (copied
// there on the device by `rec` when made): one binding for both keeps token_gate within the
// four storage buffers every device has.
const Tensor& TokenGating::codeAndMask(Recorder& rec, int64_t gh, int64_t gw) {
  auto it = codes_.find({gh, gw});
  if (it == codes_.end()) {
    const int64_t d = config_.d, n = gh * gw;
    std::vector<float> values = gatingCode(d, gh, gw);
    values.resize(size_t((n + 1) * d), 0.0f);
    it = codes_.emplace(std::make_pair(gh, gw), engine_.fromFloats({n + 1, d}, values)).first;
    copy2d(rec, mask_, d, 0, it->second.view(n * d, {d}), d, 0, 1, d);
  }
  return it->second;
}

void TokenGating::fuse(Recorder& rec, const Tensor& img, const Tensor& ray, const std::vector<int64_t>& inputs,
                       const Tensor& fused) {
  const int64_t d = config_.d, n = img.dim(-2), k = int64_t(inputs.size());
  if (!concat_.defined() || concat_.numel() != k * n * 2 * d) {
    concat_ = engine_.tensor({k * n, 2 * d});
    hidden_ = engine_.tensor({k * n, d});
  }
  // concat(image token, ray token) of the input views, gathered view by view.
  for (int64_t j = 0; j < k; ++j) {
    const int64_t v = inputs[j];
    const Tensor rows = concat_.view(j * n * 2 * d, {n, 2 * d});
    copy2d(rec, img.view(v * n * d, {n, d}), d, 0, rows, 2 * d, 0, n, d);
    copy2d(rec, ray.view(v * n * d, {n, d}), d, 0, rows, 2 * d, d, n, d);
  }
  layerNorm(rec, concat_, lnW_, Tensor(), concat_, 1e-5f);
  linear(rec, concat_, w1_, b1_, hidden_, Activation::Silu);
  linear(rec, hidden_, w2_, b2_, fused);
  add(rec, fused, viewType0_, fused);
}

void TokenGating::gate(Recorder& rec, const Tensor& fused, const Tensor& prob, const Tensor& dynPatch,
                       const Tensor& gated) {
  const std::string op = "tokenGate";
  const int64_t d = config_.d;
  const int64_t tokens = fused.numel() / d;
  const int64_t gh = dynPatch.dim(-2), gw = dynPatch.dim(-1), n = gh * gw;
  if (prob.dim(-2) != 16 * gh || prob.dim(-1) != 16 * gw)
    throw Error(op + ": pooled map " + dynPatch.describe() + " is not " + prob.describe() + " pooled by 16");
  avgPool2d(rec, prob, dynPatch, 16);
  if (dynPatch.numel() != tokens) throw Error(op + ": pooled map " + dynPatch.describe() + " does not match the tokens");
  if (config_.inputMaskingMode == "none") {
    copy2d(rec, fused, d, 0, gated, d, 0, tokens, d);
    return;
  }
  const bool soft = config_.inputMaskingMode == "soft_with_pe";
  registerModelShaders();  // model/shaders/token_gate.comp
  const Kernel& kernel = engine_.kernel({"token_gate",
                                         {Bind::Read, Bind::Read, Bind::Read, Bind::Write},
                                         sizeof(GatePush),
                                         {ops::elementLocalX(engine_.caps()), 1, 1}});
  const GatePush push{uint32_t(tokens), uint32_t(d), uint32_t(n), soft ? 0u : 1u};
  const ops::Grid grid =
      ops::linearGrid(engine_.caps(), ops::ceilDiv(uint64_t(tokens * d), uint64_t(ops::elementLocalX(engine_.caps()))), op);
  // zero_out binds the token tensor in place of the unused code and mask.
  const Tensor codes = soft ? codeAndMask(rec, gh, gw) : fused;
  rec.dispatch(kernel, {Arg::in(fused), Arg::in(dynPatch), Arg::in(codes), Arg::out(gated)}, push,
               grid.x, grid.y, 1, op);
}

}  // namespace spar
