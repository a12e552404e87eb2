// One Hiera block of SAM2.1's image encoder (official hieradet.MultiScaleBlock; reference
// reference/spar_reference/sam2.py hiera_block), on the engine:
//
//   xn = LN(x, 1e-6)                                         norm1
//   shortcut = x, or MaxPool2x2?(proj(xn)) when dim != dimOut  proj (q-pooling blocks pool it)
//   windows of xn (zero-padded), or the whole map (window 0)
//   q, k, v = qkv(windows); q max-pooled 2x2 inside each window (q-pooling blocks)
//   a = proj(softmax(q k^T / sqrt(hd)) v), laid back and cropped
//   x = shortcut + a;  x += fc2(GELU(fc1(LN(x, 1e-6))))        norm2, mlp.layers.0/1
//
// Tokens channel-last: x [H, W, dim] -> y [H', W', dimOut] with H' = H / 2 (floor) when q is
// pooled. Weights by official key under a prefix (e.g. "sam2.image_encoder.trunk.blocks.2."):
// norm1.{weight,bias}, attn.qkv.{weight,bias}, attn.proj.{weight,bias}, norm2.{weight,bias},
// mlp.layers.{0,1}.{weight,bias}, and proj.{weight,bias} when dim != dimOut. Linear weights
// may be f32 or f16; norms and biases f32. Intermediates are allocated per call.
#pragma once
#include <cstdint>
#include <string>

#include "engine/engine.h"
#include "engine/recorder.h"
#include "model/transformer_block.h"

namespace spar {

struct Sam2BlockSpec {
  int64_t dim = 0, dimOut = 0, heads = 0;
  int64_t window = 0;  // 0: global attention over the whole map
  bool qPool = false;  // the first block of stages 2-4: q and the shortcut max-pooled 2x2
};

void sam2HieraBlock(Recorder& rec, const Sam2BlockSpec& spec, const WeightLookup& weights, const std::string& prefix,
                    const Tensor& x, const Tensor& y);

}  // namespace spar
