// The model configuration the engine reads from a packed file's `__metadata__.config`
// (converter/FORMAT.md; SparConfig.to_dict() of converter/spar_convert/model_config.py).
// Parsing checks every field the engine uses and refuses, with one line naming the field,
// options the engine does not implement, so a model never runs with a silently different
// computation.
#pragma once
#include <nlohmann/json.hpp>
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace spar {

struct DinoConfig {
  int64_t embedDim = 768, depth = 12, numHeads = 12, patchSize = 16, storageTokens = 4;
  double ffnRatio = 4.0, ropeBase = 100.0, lnEps = 1e-5;
  std::string ropeNormalizeCoords = "separate";
  bool qkvBias = true, projBias = true, ffnBias = true, layerScale = true;
  std::array<float, 3> mean{0.485f, 0.456f, 0.406f}, std{0.229f, 0.224f, 0.225f};
  int64_t headDim() const { return embedDim / numHeads; }
  int64_t ffnHidden() const { return static_cast<int64_t>(embedDim * ffnRatio); }
};

struct SparConfig {
  int64_t d = 768, dHead = 64;
  int64_t encoderLayers = 12, sceneEncoderLayers = 8, decoderLayers = 12;
  int64_t cvDrpLayers = 4, cvDrpHeads = 12;
  int64_t sceneTokens = 768, poseTokens = 1;
  int64_t imageHeight = 256, imageWidth = 256, patchSize = 16;
  int64_t imageChannels = 3, rayChannels = 6;
  bool useQkNorm = true, inputWithPe = true;
  bool canonicalMiddle = true;           // canonical "middle" (V/2) or "first" (0)
  float maskThreshold = 0.5f;
  std::string inputMaskingMode = "soft_with_pe";  // soft_with_pe | zero_out | none
  bool useLseg = false;
  int64_t semanticDim = 512, semanticHidden = 64;
  double semanticLossWeight = 0.1;
  DinoConfig dino;
  nlohmann::json raw;  // the whole object as stored (lseg / clip sizes for their stages)

  int64_t heads() const { return d / dHead; }
  int64_t cvDrpHeadDim() const { return d / cvDrpHeads; }
  int64_t patchesH() const { return imageHeight / patchSize; }
  int64_t patchesW() const { return imageWidth / patchSize; }
  int64_t tokensPerView() const { return patchesH() * patchesW(); }
  int64_t canonicalIndex(int64_t views) const { return canonicalMiddle ? views / 2 : 0; }
  // Official enable_semantic_feature_supervision: semantic queries join the decoder.
  bool semanticDecoding() const { return useLseg && semanticLossWeight > 0.0; }

  // Throws spar::Error("<where>: config: <problem>") for a missing / mistyped field or an
  // option the engine does not implement.
  static SparConfig fromJson(const nlohmann::json& j, const std::string& where);
};

}  // namespace spar
