#include "model/clip_text.h"

#include <algorithm>

#include "spar/error.h"
#include "engine/ops/binary.h"
#include "engine/ops/embedding.h"
#include "engine/ops/linear.h"
#include "engine/ops/norm.h"
#include "model/stack.h"

namespace spar {
namespace {

// TransformerBlock's names -> OpenAI's under clip.transformer.resblocks.<i>., with their
// shapes in units of W (width).
enum class Dims { W, ThreeW, FourW, ThreeW_W, W_W, FourW_W, W_FourW };
struct BlockKey {
  const char* block;
  const char* clip;
  Dims dims;
};
constexpr BlockKey kBlockKeys[] = {
    {"norm1.weight", "ln_1.weight", Dims::W},
    {"norm1.bias", "ln_1.bias", Dims::W},
    {"attn.to_qkv.weight", "attn.in_proj_weight", Dims::ThreeW_W},
    {"attn.to_qkv.bias", "attn.in_proj_bias", Dims::ThreeW},
    {"attn.fc.weight", "attn.out_proj.weight", Dims::W_W},
    {"attn.fc.bias", "attn.out_proj.bias", Dims::W},
    {"norm2.weight", "ln_2.weight", Dims::W},
    {"norm2.bias", "ln_2.bias", Dims::W},
    {"mlp.mlp.0.weight", "mlp.c_fc.weight", Dims::FourW_W},
    {"mlp.mlp.0.bias", "mlp.c_fc.bias", Dims::FourW},
    {"mlp.mlp.2.weight", "mlp.c_proj.weight", Dims::W_FourW},
    {"mlp.mlp.2.bias", "mlp.c_proj.bias", Dims::W},
};

Shape shapeOf(Dims d, int64_t W) {
  switch (d) {
    case Dims::W: return {W};
    case Dims::ThreeW: return {3 * W};
    case Dims::FourW: return {4 * W};
    case Dims::ThreeW_W: return {3 * W, W};
    case Dims::W_W: return {W, W};
    case Dims::FourW_W: return {4 * W, W};
    case Dims::W_FourW: return {W, 4 * W};
  }
  throw Error("CLIP text: unknown weight shape");
}

WeightLookup blockWeights(WeightSet& weights, int64_t i, int64_t W) {
  const std::string prefix = std::string(ClipTextEncoder::kPrefix) + "transformer.resblocks." + std::to_string(i) + ".";
  return weightLookup(weights, [prefix, W](const std::string& name) -> std::pair<std::string, Shape> {
    for (const BlockKey& k : kBlockKeys)
      if (name == k.block) return {prefix + k.clip, shapeOf(k.dims, W)};
    throw Error("CLIP text: the transformer block asks for '" + name + "', which CLIP does not have");
  });
}

int64_t positive(const nlohmann::json& j, const char* key, const std::string& where) {
  if (!j.contains(key) || !j.at(key).is_number_integer() || j.at(key).get<int64_t>() <= 0)
    throw Error(where + ": config: clip." + key + " must be a positive integer");
  return j.at(key).get<int64_t>();
}

}  // namespace

ClipTextConfig ClipTextConfig::fromJson(const nlohmann::json& clip, const std::string& where) {
  if (!clip.is_object()) throw Error(where + ": config: no \"clip\" object");
  ClipTextConfig c;
  c.width = positive(clip, "width", where);
  c.layers = positive(clip, "layers", where);
  c.heads = positive(clip, "heads", where);
  c.contextLength = positive(clip, "context_length", where);
  c.vocabSize = positive(clip, "vocab_size", where);
  c.embedDim = positive(clip, "embed_dim", where);
  if (!clip.contains("ln_eps") || !clip.at("ln_eps").is_number() || !(clip.at("ln_eps").get<double>() > 0.0))
    throw Error(where + ": config: clip.ln_eps must be a positive number");
  c.lnEps = clip.at("ln_eps").get<double>();
  if (c.width % c.heads != 0 || c.headDim() % 4 != 0)
    throw Error(where + ": config: clip.width " + std::to_string(c.width) + " must be heads (" + std::to_string(c.heads) +
                ") x a multiple of 4");
  return c;
}

ClipTextEncoder::ClipTextEncoder(Engine& engine, WeightSet& weights, const ClipTextConfig& config)
    : engine_(engine), config_(config), options_(TransformerBlockOptions::clipText(config.width, config.headDim())) {
  const int64_t W = config_.width, E = config_.embedDim, V = config_.vocabSize, L = config_.contextLength;
  if (W <= 0 || config_.heads <= 0 || W % config_.heads != 0 || config_.headDim() % 4 != 0 || E <= 0 || V <= 0 ||
      L <= 0 || config_.layers < 0)
    throw Error("CLIP text: unusable configuration (width " + std::to_string(W) + ", " + std::to_string(config_.heads) +
                " heads)");
  options_.lnEps = static_cast<float>(config_.lnEps);
  const std::string p = kPrefix;
  tokenEmbedding_ = weights.require(p + "token_embedding.weight", {V, W});
  positional_ = weights.require(p + "positional_embedding", {L, W}, DType::F32);
  lnFinalW_ = weights.require(p + "ln_final.weight", {W}, DType::F32);
  lnFinalB_ = weights.require(p + "ln_final.bias", {W}, DType::F32);

  // x @ text_projection [W, E] is linear(x, P^T): transposed once here.
  const std::vector<float> proj = engine_.download(weights.require(p + "text_projection", {W, E}, DType::F32));
  std::vector<float> projT(proj.size());
  for (int64_t i = 0; i < W; ++i)
    for (int64_t j = 0; j < E; ++j) projT[size_t(j * W + i)] = proj[size_t(i * E + j)];
  // In the matrix type, as the file's other matrices; under q8 / q4 as f32, as their packs keep
  // it (the projection is outside the quantization rule, model/quantized_matrices.h).
  projection_ = engine_.fromFloats({E, W}, projT, isQuantized(weights.matrixType()) ? DType::F32 : weights.matrixType());

  blocks_.reserve(size_t(config_.layers));
  for (int64_t i = 0; i < config_.layers; ++i) blocks_.emplace_back(engine_, options_, blockWeights(weights, i, W));
}

int64_t ClipTextEncoder::endPosition(const int32_t* row, int64_t length) {
  return static_cast<int64_t>(std::max_element(row, row + length) - row);  // first maximum, as torch.argmax
}

void ClipTextEncoder::forward(Recorder& rec, const std::vector<int32_t>& ids, const Tensor& embeddings,
                              TransformerWorkspace& ws) {
  const int64_t L = config_.contextLength, W = config_.width, E = config_.embedDim;
  if (ids.empty() || ids.size() % size_t(L) != 0)
    throw Error("CLIP text: ids must be [P, " + std::to_string(L) + "] with P >= 1, got " + std::to_string(ids.size()) +
                " values");
  const int64_t P = static_cast<int64_t>(ids.size()) / L;
  if (embeddings.shape() != Shape{P, E} || embeddings.dtype() != DType::F32)
    throw Error("CLIP text: embeddings must be f32 [" + std::to_string(P) + ", " + std::to_string(E) + "], got " +
                embeddings.describe());
  for (int32_t id : ids)
    if (id < 0 || id >= config_.vocabSize)
      throw Error("CLIP text: token id " + std::to_string(id) + " outside the vocabulary of " +
                  std::to_string(config_.vocabSize));

  // Positions past the batch's last end token never reach a pooled row (causal attention).
  std::vector<int64_t> ends(static_cast<size_t>(P));
  int64_t N = 1;
  for (int64_t p = 0; p < P; ++p) {
    ends[size_t(p)] = endPosition(&ids[size_t(p * L)], L);
    N = std::max(N, ends[size_t(p)] + 1);
  }
  std::vector<int32_t> cut(static_cast<size_t>(P * N)), pooledRows(static_cast<size_t>(P));
  for (int64_t p = 0; p < P; ++p) {
    std::copy_n(&ids[size_t(p * L)], N, &cut[size_t(p * N)]);
    pooledRows[size_t(p)] = static_cast<int32_t>(p * N + ends[size_t(p)]);
  }
  const Tensor idsT = engine_.tensor({P, N}, DType::I32);
  engine_.write(idsT, cut.data(), cut.size() * sizeof(int32_t));
  const Tensor rowsT = engine_.tensor({P}, DType::I32);
  engine_.write(rowsT, pooledRows.data(), pooledRows.size() * sizeof(int32_t));
  const Tensor x = engine_.tensor({P, N, W});
  const Tensor pooled = engine_.tensor({P, W});
  const Tensor normed = engine_.tensor({P, W});

  embedding(rec, tokenEmbedding_, idsT, x);
  add(rec, x, positional_.view(0, {N, W}), x);
  ws.reserve(engine_, P * N, options_);
  forwardBlocks(rec, blocks_, x, ws);
  embedding(rec, x.reshape({P * N, W}), rowsT, pooled);  // the end-token rows
  layerNorm(rec, pooled, lnFinalW_, lnFinalB_, normed, options_.lnEps);
  linear(rec, normed, projection_, Tensor(), embeddings);
}

}  // namespace spar
