// The pre-norm transformer block of every SPAR stack (pose encoder, scene encoder, decoder,
// CV-DRP) and of the backbones (DINOv3, LSeg's ViT, CLIP's text encoder), on the engine:
//
//   x += ls1(fc(attention(qknorm(split(to_qkv(norm1(x)))))))
//   x += ls2(mlp.2(act(mlp.0(norm2(x)))))
//
// One implementation; what differs between stacks is in TransformerBlockOptions. Weights are
// engine tensors looked up by the official key names (reference/spar_reference/transformer.py)
// under a prefix, e.g. "transformer_encoder.3.":
//
//   norm1.weight [D]  norm1.bias [D]           (bias with lnBias)
//   attn.to_qkv.weight [3D, D]  attn.to_qkv.bias [3D]   (bias with qkvBias)
//   attn.q_norm.weight [dh]  attn.k_norm.weight [dh]    (with qkNorm)
//   attn.fc.weight [D, D]  attn.fc.bias [D]    (bias with fcBias)
//   norm2.weight [D]  norm2.bias [D]
//   mlp.mlp.0.weight [H, D]  mlp.mlp.0.bias [H]  mlp.mlp.2.weight [D, H]  mlp.mlp.2.bias [D]
//   ls1.gamma [D]  ls2.gamma [D]               (with layerScale)
//
// Linear weights and biases may be f32 or f16; norm weights, LayerScale gammas and (with
// maskKBias) the qkv bias must be f32. Activations are f32. Everything runs as engine
// dispatches recorded into the caller's Recorder; nothing is computed on the CPU.
#pragma once
#include <cstdint>
#include <functional>
#include <string>
#include <type_traits>
#include <vector>

#include "engine/engine.h"
#include "engine/ops/activation.h"
#include "engine/recorder.h"

namespace spar {

struct TransformerBlockOptions {
  int64_t dim = 0;        // D = heads * headDim
  int64_t headDim = 64;   // dh (multiple of 4)
  int64_t mlpHidden = 0;  // H; 0 means 4 * D
  bool lnBias = false;    // norm1/norm2 have a bias (SPAR: no)
  float lnEps = 1e-5f;
  bool qkvBias = false, fcBias = false, mlpBias = false;
  bool qkNorm = true;     // per-head RMSNorm of q and k with weight
  float qkNormEps = 1e-5f;
  bool layerScale = false;  // ls1.gamma, ls2.gamma (DINOv3)
  bool maskKBias = false;   // the k third of the qkv bias is zeroed (DINOv3)
  bool causal = false;      // keys after the query masked (CLIP text)
  Activation activation = Activation::Gelu;  // exact erf GELU; QuickGelu for CLIP

  int64_t heads() const { return headDim > 0 ? dim / headDim : 0; }
  int64_t hidden() const { return mlpHidden > 0 ? mlpHidden : 4 * dim; }

  // SPAR's stacks (official QK_Norm_TransformerBlock defaults).
  static TransformerBlockOptions spar(int64_t dim, int64_t headDim);
  // CLIP text transformer: LayerNorm with bias, all linear biases, no QK-norm, QuickGELU, causal.
  static TransformerBlockOptions clipText(int64_t dim, int64_t headDim);
  // DINOv3 ViT: LayerNorm with bias, biases, LayerScale, masked k bias, GELU, no QK-norm.
  static TransformerBlockOptions dinov3(int64_t dim, int64_t headDim);
};

// Weight lookup by full key name: the tensor, or an undefined Tensor (or a throw) when the key is
// missing. `padded`, where the lookup has it, gives the tensor stored with zeros appended up to a
// larger shape (undefined where it cannot: a quantized matrix): the block asks for its MLP that
// way where the device's plan lays the hidden rows out wider (engine/ops/row_padding.h), so that
// only the padded copy reaches the device. A lookup without it gets the MLP as stored.
struct WeightLookup {
  std::function<Tensor(const std::string& name)> find;
  std::function<Tensor(const std::string& name, const Shape& paddedShape)> padded;

  WeightLookup() = default;
  template <class F, class = std::enable_if_t<std::is_invocable_r_v<Tensor, F&, const std::string&>>>
  WeightLookup(F f) : find(std::move(f)) {}
  Tensor operator()(const std::string& name) const { return find(name); }
  explicit operator bool() const { return bool(find); }
};

// Rotary position embedding of the q and k heads, after their norm (DINOv3's blocks; none of
// SPAR's own stacks): rope()'s tables and prefix (engine/ops/rope.h), applied by the attention
// kernel as it reads the heads (engine/ops/attention.h, QkPrep).
struct BlockRope {
  Tensor sin, cos;  // f32 [N - prefix, headDim]
  int64_t prefix = 0;
};

// Scratch activations shared by every block of every stack (plan memory once, reuse across
// layers). reserve() allocates only when the request exceeds what is already held, so one
// workspace sized for the largest (tokens, D, H) serves all stacks. Tensors handed out are
// views at the start of the held buffers. Not thread-safe; one workspace per Recorder in
// flight (blocks recorded into the same Recorder may share it: the recorder orders them).
class TransformerWorkspace {
 public:
  // Makes room for `tokens` = B * N rows of width dim, hidden width `hidden`.
  void reserve(Engine& engine, int64_t tokens, int64_t dim, int64_t hidden);
  void reserve(Engine& engine, int64_t tokens, const TransformerBlockOptions& o) {
    reserve(engine, tokens, o.dim, o.hidden());
  }

  // Views for a [B, N, *] pass (throw if reserve() was not large enough).
  Tensor norm(int64_t b, int64_t n, int64_t d) const;    // norm1/norm2 output, then fc output
  Tensor attn(int64_t b, int64_t n, int64_t d) const;    // attention output, then mlp.2 output
  Tensor qkv(int64_t b, int64_t n, int64_t d) const;     // [B, N, 3D], aliases hidden()
  Tensor hidden(int64_t b, int64_t n, int64_t h) const;  // [B, N, H]

  size_t bytes() const;      // device memory held
  int allocations() const { return allocations_; }  // how many times buffers were (re)allocated

 private:
  Tensor view(const Tensor& t, int64_t elems, const Shape& shape, const char* what) const;
  Tensor norm_, attn_, big_;  // [cap * D], [cap * D], [cap * max(3D, H)]
  int allocations_ = 0;
};

class TransformerBlock {
 public:
  // Looks up and checks every weight the options call for (prefix + official name; a prefix
  // without a trailing '.' gets one). With maskKBias the masked qkv bias is prepared here by
  // one engine dispatch.
  TransformerBlock(Engine& engine, const TransformerBlockOptions& options, const WeightLookup& weights,
                   const std::string& prefix = "");

  // The key names (without prefix) the options call for.
  static std::vector<std::string> weightNames(const TransformerBlockOptions& options);

  // x: [B, N, D] f32, updated in place. ws must have been reserved for B * N tokens.
  // A block is 7 dispatches (layerNorm, qkv, attention with the q / k norm and RoPE, fc with its
  // residual add and layer scale, layerNorm, mlp.0 with its activation, mlp.2 likewise).
  void forward(Recorder& rec, const Tensor& x, const TransformerWorkspace& ws, const BlockRope* rope = nullptr) const;

  const TransformerBlockOptions& options() const { return o_; }
  // The MLP's hidden row as laid out on the device: options().hidden(), or wider by
  // ops::kRowPadding zeros where the plan pads aliased rows and the lookup can pad.
  int64_t hiddenRow() const { return hiddenRow_; }

 private:
  TransformerBlockOptions o_;
  int64_t hiddenRow_ = 0;
  Tensor norm1W_, norm1B_, qkvW_, qkvB_, qkNormW_, fcW_, fcB_, norm2W_, norm2B_;
  // with a layer scale, fcB_ and mlp2B_ hold (bias, gamma) texels (layerScaleEpilogue)
  Tensor mlp0W_, mlp0B_, mlp2W_, mlp2B_;
};

// Runs blocks one after the other on x (a stack without its final norm).
void forwardBlocks(Recorder& rec, const std::vector<TransformerBlock>& blocks, const Tensor& x,
                   const TransformerWorkspace& ws, const BlockRope* rope = nullptr);

}  // namespace spar
