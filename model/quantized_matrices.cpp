#include "model/quantized_matrices.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <set>

#include "spar/error.h"

namespace spar {

namespace {

// `name` with every all-digit component (a layer index) written '#'.
std::string withLayerIndices(const std::string& name) {
  std::string out;
  size_t begin = 0;
  while (begin <= name.size()) {
    size_t end = name.find('.', begin);
    if (end == std::string::npos) end = name.size();
    const std::string part = name.substr(begin, end - begin);
    const bool digits = !part.empty() && std::all_of(part.begin(), part.end(), [](char c) { return c >= '0' && c <= '9'; });
    if (begin) out += '.';
    out += digits ? std::string("#") : part;
    begin = end + 1;
  }
  return out;
}

std::set<std::string> quantizedPatterns() {
  std::set<std::string> p = {"clip.token_embedding.weight"};
  for (const char* stack : {"transformer_encoder", "transformer_encoder_geom", "transformer_decoder",
                            "cv_drp.estimator.transformer_layers"})
    for (const char* layer : {".#.attn.to_qkv.weight", ".#.attn.fc.weight", ".#.mlp.mlp.#.weight"})
      p.insert(std::string(stack) + layer);
  for (const char* vit : {"dino.blocks", "lseg.pretrained.model.blocks"})
    for (const char* layer : {".#.attn.qkv.weight", ".#.attn.proj.weight", ".#.mlp.fc1.weight", ".#.mlp.fc2.weight"})
      p.insert(std::string(vit) + layer);
  for (const char* layer : {".#.attn.in_proj_weight", ".#.attn.out_proj.weight", ".#.mlp.c_fc.weight", ".#.mlp.c_proj.weight"})
    p.insert(std::string("clip.transformer.resblocks") + layer);
  // LSeg's convolutions but the transposed ones of hooks 1 and 2 (act_postprocess1.4 / 2.4)
  for (const char* conv : {"lseg.pretrained.act_postprocess1.3.weight", "lseg.pretrained.act_postprocess2.3.weight",
                           "lseg.pretrained.act_postprocess3.3.weight", "lseg.pretrained.act_postprocess4.3.weight",
                           "lseg.pretrained.act_postprocess4.4.weight"})
    p.insert(conv);
  for (int i = 1; i <= 4; ++i) {
    const std::string n = std::to_string(i);
    p.insert("lseg.scratch.layer" + n + "_rn.weight");
    for (const char* unit : {".resConfUnit1.conv1.weight", ".resConfUnit1.conv2.weight", ".resConfUnit2.conv1.weight",
                             ".resConfUnit2.conv2.weight"})
      p.insert("lseg.scratch.refinenet" + n + unit);
  }
  for (const char* seq : {"semantic_token_decoder", "mlp_fuse", "pe_embedder", "temporal_pe_embedder", "image_tokenizer",
                          "target_pose_tokenizer", "target_pose_tokenizer2", "target_pose_tokenizer_semantic",
                          "cv_drp.estimator.fusion_mlp.net"})
    p.insert(std::string(seq) + ".#.weight");
  return p;
}

}  // namespace

Shape quantizedMatrixShape(const Shape& shape) {
  if (shape.empty()) return {0, 0};
  int64_t k = 1;
  for (size_t i = 1; i < shape.size(); ++i) k *= shape[i];
  return {shape[0], k};
}

bool isQuantizedMatrix(const std::string& name, const Shape& shape) {
  // Kept in step with QUANTIZED_MATRICES of converter/spar_convert/convert.py by
  // tests/test_spar_precision.cpp (QuantizedRuleIsTheConverters). Names are matched as they
  // are (LSeg's convolutions: hook and unit numbers are part of the name) and with every
  // layer index written '#'.
  static const std::set<std::string> patterns = quantizedPatterns();
  return (shape.size() == 2 || shape.size() == 4) && quantizedMatrixShape(shape)[1] % 32 == 0 &&
         (patterns.count(name) != 0 || patterns.count(withLayerIndices(name)) != 0);
}

std::vector<uint8_t> quantizeRows(const std::vector<float>& w, int64_t N, int64_t K, DType type) {
  if (!isQuantized(type) || K % 32 || int64_t(w.size()) != N * K)
    throw Error("quantizeRows: " + std::string(dtypeName(type)) + shapeString({N, K}) + " of " +
                std::to_string(w.size()) + " values");
  const int bits = type == DType::Q8 ? 8 : 4, levels = bits == 8 ? 127 : 7;
  const size_t codeBytes = size_t(K) * size_t(bits) / 8, rowBytes = codeBytes + size_t(K) / 8;
  std::vector<uint8_t> out(size_t(N) * rowBytes, 0);
  for (int64_t n = 0; n < N; ++n) {
    uint8_t* row = out.data() + size_t(n) * rowBytes;
    for (int64_t b = 0; b < K / 32; ++b) {
      const float* block = w.data() + n * K + b * 32;
      double amax = 0;
      for (int j = 0; j < 32; ++j) amax = std::max(amax, std::abs(double(block[j])));
      const float scale = float(amax / levels);
      std::memcpy(row + codeBytes + size_t(b) * 4, &scale, 4);
      for (int j = 0; j < 32; ++j) {
        const int64_t k = b * 32 + j;
        const double c = scale > 0 ? std::nearbyint(double(block[j]) / double(scale)) : 0.0;
        const int code = int(std::clamp(c, double(-levels), double(levels)));
        if (bits == 8) row[k] = uint8_t(int8_t(code));
        else row[k / 2] |= uint8_t((code + 8) << (4 * (k & 1)));
      }
    }
  }
  return out;
}

}  // namespace spar
