// SAM2.1's image encoder (model/sam2_image_encoder.h).
#include "model/sam2_image_encoder.h"

#include <algorithm>

#include "spar/error.h"
#include "engine/ops/binary.h"
#include "engine/ops/conv2d.h"
#include "engine/ops/linear.h"
#include "model/sam2_position_table.h"
#include "model/sam2_preprocess.h"
#include "model/sam2_windows.h"

namespace spar {

Sam2ImageEncoder::Sam2ImageEncoder(Engine& engine, const Sam2Config& config, WeightLookup weights, std::string prefix)
    : engine_(engine), config_(config), weights_(std::move(weights)), prefix_(std::move(prefix)) {
  const int64_t side = config_.tokenSide();
  positionTable_ = engine_.tensor({side * side, config_.embedDim});
  Recorder rec(engine_);
  sam2PositionTable(rec, weight("image_encoder.trunk.pos_embed"), weight("image_encoder.trunk.pos_embed_window"),
                    positionTable_);
  rec.run();
}

Tensor Sam2ImageEncoder::weight(const std::string& name) const {
  Tensor t = weights_(prefix_ + name);
  if (!t.defined()) throw Error("SAM2 image encoder: missing weight " + prefix_ + name);
  return t;
}

Sam2ImageFeatures Sam2ImageEncoder::encode(Recorder& rec, const Tensor& images, int64_t view,
                                           const std::function<void(Recorder&)>& flush) const {
  const int64_t S = config_.imageSize, side = config_.tokenSide(), C0 = config_.embedDim, d = config_.dModel;
  const Tensor input = engine_.tensor({1, 3, S, S});
  sam2Preprocess(rec, images, view, input.reshape({3, S, S}));
  const Tensor embedded = engine_.tensor({1, C0, side, side});
  Conv2dParams patch;
  patch.stride = int(Sam2Config::kPatchStride);
  patch.padY = patch.padX = 3;
  conv2d(rec, input, weight("image_encoder.trunk.patch_embed.proj.weight"),
         weight("image_encoder.trunk.patch_embed.proj.bias"), embedded, patch);
  Tensor x = engine_.tensor({side * side, C0});
  sam2ChannelsLast(rec, embedded, x);
  x = x.reshape({side, side, C0});
  add(rec, x, positionTable_.reshape({side, side, C0}), x);

  Sam2ImageFeatures f;
  const std::vector<int64_t> ends = config_.stageEnds();
  const std::vector<Sam2BlockSpec> blocks = config_.blocks();
  for (size_t i = 0; i < blocks.size(); ++i) {
    const Sam2BlockSpec& b = blocks[i];
    const int64_t H = b.qPool ? x.dim(0) / 2 : x.dim(0), W = b.qPool ? x.dim(1) / 2 : x.dim(1);
    const Tensor y = engine_.tensor({H, W, b.dimOut});
    sam2HieraBlock(rec, b, weights_, prefix_ + "image_encoder.trunk.blocks." + std::to_string(i) + ".", x, y);
    x = y;
    if (std::find(ends.begin(), ends.end(), int64_t(i)) != ends.end()) f.stages.push_back(y);
    if (flush) flush(rec);
  }
  if (f.stages.size() != 4) throw Error("SAM2 image encoder: the trunk gave " + std::to_string(f.stages.size()) + " stages");

  // FPN neck: convs.0 takes the deepest stage; 1x1 convs are GEMMs on channel-last tokens
  auto lateral = [&](int64_t level) {
    const Tensor& s = f.stages[size_t(level)];
    const std::string conv = "image_encoder.neck.convs." + std::to_string(3 - level) + ".conv.";
    const Tensor w = weight(conv + "weight");
    const Tensor out = engine_.tensor({s.dim(0), s.dim(1), d});
    linear(rec, s, w.reshape({w.dim(0), w.dim(1)}), weight(conv + "bias"), out);
    return out;
  };
  const Tensor l3 = lateral(3), l2 = lateral(2), l1 = lateral(1), l0 = lateral(0);
  const Tensor level2 = engine_.tensor(l2.shape());
  sam2AddNearestUp2x(rec, l2, l3, level2);
  const Tensor noMem = weight("no_mem_embed");
  f.imageEmbed = engine_.tensor({level2.dim(0) * level2.dim(1), d});
  add(rec, level2.reshape({level2.dim(0) * level2.dim(1), d}), noMem.reshape({d}), f.imageEmbed);
  auto conv1x1 = [&](const Tensor& level, const std::string& name) {
    const Tensor w = weight("sam_mask_decoder." + name + ".weight");
    const Tensor out = engine_.tensor({level.dim(0) * level.dim(1), w.dim(0)});
    linear(rec, level.reshape({level.dim(0) * level.dim(1), d}), w.reshape({w.dim(0), w.dim(1)}),
           weight("sam_mask_decoder." + name + ".bias"), out);
    return out;
  };
  f.featS0 = conv1x1(l0, "conv_s0");
  f.featS1 = conv1x1(l1, "conv_s1");
  return f;
}

}  // namespace spar
