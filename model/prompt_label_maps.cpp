// Prompts' embeddings and label maps on the device (prompt_label_maps.h).
#include "model/prompt_label_maps.h"

#include <chrono>

#include "engine/recorder.h"
#include "model/clip_text.h"
#include "model/label_maps.h"
#include "model/transformer_block.h"

namespace spar {

PromptEmbeddings encodePrompts(Engine& engine, const PackedModel& model, const SparConfig& config, DType weightType,
                               const std::vector<int32_t>& ids, int64_t prompts) {
  const auto t = std::chrono::steady_clock::now();
  PromptEmbeddings p;
  p.prompts = prompts;
  p.weights = std::make_unique<WeightSet>(engine, model, weightType);
  ClipTextEncoder encoder(engine, *p.weights, ClipTextConfig::fromJson(config.raw.at("clip"), model.path()));
  p.text = engine.tensor({prompts, encoder.config().embedDim});
  TransformerWorkspace ws;
  Recorder rec(engine, true);
  encoder.forward(rec, ids, p.text, ws);
  rec.run();
  p.gpuMs = rec.totalMs();
  p.buildMs = rec.totalBuildMs();
  p.counts = rec.lastRunTotal();
  p.wallMs = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t).count();
  return p;
}

LabelMapsOut computeLabelMaps(Engine& engine, const Tensor& features, const PromptEmbeddings& prompts,
                              std::vector<float>* scores) {
  const int64_t views = features.dim(0), h = features.dim(2), w = features.dim(3);
  const Tensor maps = engine.tensor({views, 2 * h, 2 * w}, DType::I32);
  const Tensor logits = scores ? engine.tensor({views, prompts.prompts, h, w}) : Tensor();
  Recorder rec(engine, true);
  labelMaps(rec, features, prompts.text, maps, logits);
  rec.run();
  LabelMapsOut out;
  out.gpuMs = rec.totalMs();
  out.buildMs = rec.totalBuildMs();
  out.counts = rec.lastRunTotal();
  if (scores) {
    const std::vector<float> sc = engine.download(logits);
    scores->insert(scores->end(), sc.begin(), sc.end());
  }
  std::vector<int32_t> all(size_t(maps.numel()));
  engine.read(maps, all.data(), all.size() * sizeof(int32_t));
  const size_t per = size_t(2 * h) * size_t(2 * w);
  for (int64_t j = 0; j < views; ++j) out.maps.emplace_back(all.begin() + j * per, all.begin() + (j + 1) * per);
  return out;
}

}  // namespace spar
