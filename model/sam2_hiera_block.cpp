// One Hiera block (model/sam2_hiera_block.h): general ops (engine/ops) and the window layout
// kernels (model/sam2_windows.h).
#include "model/sam2_hiera_block.h"

#include "spar/error.h"
#include "engine/ops/attention.h"
#include "engine/ops/binary.h"
#include "engine/ops/copy2d.h"
#include "engine/ops/linear.h"
#include "engine/ops/norm.h"
#include "model/sam2_windows.h"

namespace spar {

void sam2HieraBlock(Recorder& rec, const Sam2BlockSpec& s, const WeightLookup& weights, const std::string& prefix,
                    const Tensor& x, const Tensor& y) {
  const TransformerBlockCount count(rec);
  const std::string op = "sam2HieraBlock " + prefix;
  Engine& engine = rec.engine();
  if (s.dim <= 0 || s.dimOut <= 0 || s.heads <= 0 || s.dimOut % s.heads || s.window < 0)
    throw Error(op + ": bad block sizes");
  if (s.qPool && s.window % 2) throw Error(op + ": q pooling needs an even window (or global attention)");
  if (!x.defined() || x.rank() != 3 || x.dim(2) != s.dim)
    throw Error(op + ": x must be [H, W, " + std::to_string(s.dim) + "], got " + x.describe());
  const int64_t H = x.dim(0), W = x.dim(1), D = s.dim, Do = s.dimOut;
  const int64_t Ho = s.qPool ? H / 2 : H, Wo = s.qPool ? W / 2 : W;
  if (!y.defined() || y.rank() != 3 || y.dim(0) != Ho || y.dim(1) != Wo || y.dim(2) != Do)
    throw Error(op + ": y must be [" + std::to_string(Ho) + ", " + std::to_string(Wo) + ", " + std::to_string(Do) +
                "], got " + y.describe());
  if (s.dim != s.dimOut && !s.qPool) throw Error(op + ": a width change without q pooling is not Hiera's");
  auto w = [&](const std::string& name) {
    Tensor t = weights(prefix + name);
    if (!t.defined()) throw Error(op + ": missing weight " + prefix + name);
    return t;
  };

  // norm1; the shortcut
  const Tensor xn = engine.tensor({H, W, D});
  layerNorm(rec, x, w("norm1.weight"), w("norm1.bias"), xn, 1e-6f);
  Tensor shortcut = x;
  if (D != Do) {
    const Tensor projected = engine.tensor({1, H, W, Do});
    linear(rec, xn, w("proj.weight"), w("proj.bias"), projected.reshape({H, W, Do}));
    shortcut = engine.tensor({1, Ho, Wo, Do});
    sam2MaxPool2x2(rec, projected, shortcut);
    shortcut = shortcut.reshape({Ho, Wo, Do});
  }

  // windows (a global block is one window: the whole map)
  const int64_t win = s.window;
  const int64_t nW = win > 0 ? sam2WindowsAlong(H, win) * sam2WindowsAlong(W, win) : 1;
  const int64_t tokens = win > 0 ? win * win : H * W;
  Tensor windows = xn.reshape({1, H * W, D});
  if (win > 0) {
    windows = engine.tensor({nW, tokens, D});
    sam2WindowPartition(rec, xn, win, windows);
  }
  const Tensor qkv = engine.tensor({nW, tokens, 3 * Do});
  linear(rec, windows, w("attn.qkv.weight"), w("attn.qkv.bias"), qkv);

  // q (pooled inside each window on q-pooling blocks)
  const int64_t hd = Do / s.heads;
  HeadsView q{qkv, 0};
  int64_t qTokens = tokens;
  const int64_t side = win > 0 ? win : 0;
  if (s.qPool) {
    const int64_t qh = win > 0 ? win : H, qw = win > 0 ? win : W;
    const Tensor qOnly = engine.tensor({nW, qh, qw, Do});
    slice(rec, qkv, -1, 0, Do, qOnly.reshape({nW, tokens, Do}));
    const Tensor pooled = engine.tensor({nW, qh / 2, qw / 2, Do});
    sam2MaxPool2x2(rec, qOnly, pooled);
    qTokens = (qh / 2) * (qw / 2);
    q = HeadsView{pooled.reshape({nW, qTokens, Do}), 0};
  }
  const Tensor attended = engine.tensor({nW, qTokens, Do});
  attention(rec, q, HeadsView{qkv, Do}, HeadsView{qkv, 2 * Do}, HeadsView{attended, 0}, int(s.heads), int(hd));
  const Tensor projectedOut = engine.tensor({nW, qTokens, Do});
  linear(rec, attended, w("attn.proj.weight"), w("attn.proj.bias"), projectedOut);

  // back to the map (cropped), plus the shortcut
  Tensor merged;
  if (win > 0) {
    merged = engine.tensor({Ho, Wo, Do});
    sam2WindowMerge(rec, projectedOut, s.qPool ? side / 2 : side, merged);
  } else {
    merged = projectedOut.reshape({Ho, Wo, Do});
  }
  add(rec, shortcut, merged, y);

  // MLP
  const Tensor yn = engine.tensor({Ho, Wo, Do});
  layerNorm(rec, y, w("norm2.weight"), w("norm2.bias"), yn, 1e-6f);
  const Tensor hidden = engine.tensor({Ho, Wo, 4 * Do});
  linear(rec, yn, w("mlp.layers.0.weight"), w("mlp.layers.0.bias"), hidden, Activation::Gelu);
  const Tensor mlpOut = engine.tensor({Ho, Wo, Do});
  linear(rec, hidden, w("mlp.layers.1.weight"), w("mlp.layers.1.bias"), mlpOut);
  add(rec, y, mlpOut, y);
}

}  // namespace spar
