#include "model/spar_config.h"

#include <cmath>

#include "spar/error.h"

namespace spar {
namespace {

constexpr int64_t kMaxConfigInteger = int64_t(1) << 20;

// Field readers: a missing field keeps the default only where the converter may omit it;
// a present field of the wrong type is an error.
struct Reader {
  const nlohmann::json& j;
  std::string where;

  [[noreturn]] void fail(const std::string& what) const { throw Error(where + ": config: " + what); }
  // Finite and far inside float's range (fields stored as float would otherwise become infinite).
  static bool sane(double x) { return std::isfinite(x) && std::abs(x) <= 1e30; }

  const nlohmann::json* find(const char* key) const {
    auto it = j.find(key);
    return it == j.end() ? nullptr : &*it;
  }
  int64_t integer(const char* key, int64_t def, bool required = true, int64_t min = 1) const {
    const nlohmann::json* v = find(key);
    if (!v) {
      if (required) fail(std::string("missing field '") + key + "'");
      return def;
    }
    if (!v->is_number_integer()) fail(std::string("field '") + key + "' is not an integer");
    int64_t x = v->get<int64_t>();
    // No size of a SPAR (widths, depths, heads, tokens, pixels) comes near 2^20: a larger
    // value is a damaged or hostile file, refused here rather than as a failed allocation.
    if (x < min || x > kMaxConfigInteger)
      fail(std::string("field '") + key + "' = " + std::to_string(x) + " is out of range (" + std::to_string(min) +
           " to " + std::to_string(kMaxConfigInteger) + ")");
    return x;
  }
  double number(const char* key, double def, bool required = true) const {
    const nlohmann::json* v = find(key);
    if (!v) {
      if (required) fail(std::string("missing field '") + key + "'");
      return def;
    }
    if (!v->is_number()) fail(std::string("field '") + key + "' is not a number");
    const double x = v->get<double>();
    if (!sane(x)) fail(std::string("field '") + key + "' is not a finite number of sane size");
    return x;
  }
  bool boolean(const char* key, bool def, bool required = true) const {
    const nlohmann::json* v = find(key);
    if (!v) {
      if (required) fail(std::string("missing field '") + key + "'");
      return def;
    }
    if (!v->is_boolean()) fail(std::string("field '") + key + "' is not a boolean");
    return v->get<bool>();
  }
  std::string string(const char* key, const std::string& def, bool required = true) const {
    const nlohmann::json* v = find(key);
    if (!v) {
      if (required) fail(std::string("missing field '") + key + "'");
      return def;
    }
    if (!v->is_string()) fail(std::string("field '") + key + "' is not a string");
    return v->get<std::string>();
  }
  std::array<float, 3> triple(const char* key, std::array<float, 3> def) const {
    const nlohmann::json* v = find(key);
    if (!v) return def;
    const std::string bad = std::string("field '") + key + "' is not a list of 3 finite numbers of sane size";
    if (!v->is_array() || v->size() != 3) fail(bad);
    std::array<float, 3> out{};
    for (size_t i = 0; i < 3; ++i) {
      if (!(*v)[i].is_number() || !sane((*v)[i].get<double>())) fail(bad);
      out[i] = static_cast<float>((*v)[i].get<double>());
    }
    return out;
  }
};

DinoConfig parseDino(const nlohmann::json& j, const std::string& where) {
  if (!j.is_object()) throw Error(where + ": config: field 'dino' is not an object");
  Reader r{j, where + ": config.dino"};
  DinoConfig c;
  c.embedDim = r.integer("embed_dim", c.embedDim);
  c.depth = r.integer("depth", c.depth);
  c.numHeads = r.integer("num_heads", c.numHeads);
  c.patchSize = r.integer("patch_size", c.patchSize);
  c.storageTokens = r.integer("n_storage_tokens", c.storageTokens, false, 0);
  c.ffnRatio = r.number("ffn_ratio", c.ffnRatio, false);
  c.ropeBase = r.number("rope_base", c.ropeBase, false);
  c.ropeNormalizeCoords = r.string("rope_normalize_coords", c.ropeNormalizeCoords, false);
  c.lnEps = r.number("ln_eps", c.lnEps, false);
  c.qkvBias = r.boolean("qkv_bias", c.qkvBias, false);
  c.projBias = r.boolean("proj_bias", c.projBias, false);
  c.ffnBias = r.boolean("ffn_bias", c.ffnBias, false);
  c.mean = r.triple("mean", c.mean);
  c.std = r.triple("std", c.std);
  if (c.embedDim % c.numHeads != 0) r.fail("embed_dim is not a multiple of num_heads");
  if (c.headDim() % 4 != 0) r.fail("head dim (embed_dim / num_heads) must be a multiple of 4 for RoPE");
  if (c.ropeNormalizeCoords != "separate" && c.ropeNormalizeCoords != "max" && c.ropeNormalizeCoords != "min")
    r.fail("rope_normalize_coords '" + c.ropeNormalizeCoords + "' is not one of separate, max, min");
  for (float s : c.std)
    if (!(s > 0.0f)) r.fail("std must be positive");
  return c;
}

}  // namespace

SparConfig SparConfig::fromJson(const nlohmann::json& j, const std::string& where) {
  if (!j.is_object()) throw Error(where + ": config: not a JSON object");
  Reader r{j, where};
  SparConfig c;
  c.raw = j;
  c.d = r.integer("d", c.d);
  c.dHead = r.integer("d_head", c.dHead);
  c.encoderLayers = r.integer("encoder_n_layer", c.encoderLayers, true, 0);
  c.sceneEncoderLayers = r.integer("encoder_geom_n_layer", c.sceneEncoderLayers, true, 0);
  c.decoderLayers = r.integer("decoder_n_layer", c.decoderLayers, true, 0);
  c.cvDrpLayers = r.integer("cv_drp_n_layer", c.cvDrpLayers, true, 0);
  c.cvDrpHeads = r.integer("cv_drp_n_heads", c.cvDrpHeads);
  c.sceneTokens = r.integer("scene_tokens", c.sceneTokens);
  c.poseTokens = r.integer("pose_tokens", c.poseTokens);
  c.imageHeight = r.integer("image_height", c.imageHeight);
  c.imageWidth = r.integer("image_width", c.imageWidth);
  c.patchSize = r.integer("patch_size", c.patchSize);
  c.imageChannels = r.integer("image_channels", c.imageChannels);
  c.rayChannels = r.integer("ray_channels", c.rayChannels);
  c.useQkNorm = r.boolean("use_qk_norm", c.useQkNorm);
  c.inputWithPe = r.boolean("input_with_pe", c.inputWithPe);
  std::string canonical = r.string("canonical", "middle");
  c.maskThreshold = static_cast<float>(r.number("mask_threshold", c.maskThreshold));
  c.inputMaskingMode = r.string("input_masking_mode", c.inputMaskingMode);
  std::string poseRep = r.string("pose_representation", "6d");
  std::string pluckerNorm = r.string("plucker_norm_mode", "none");
  c.useLseg = r.boolean("use_lseg", c.useLseg);
  c.semanticDim = r.integer("semantic_dim", c.semanticDim);
  c.semanticHidden = r.integer("semantic_hidden", c.semanticHidden);
  c.semanticLossWeight = r.number("semantic_loss_weight", c.semanticLossWeight);
  auto dino = j.find("dino");
  if (dino == j.end()) r.fail("missing field 'dino'");
  c.dino = parseDino(*dino, where);

  // What the engine implements (the official spar.yaml uses all of these).
  if (c.d % c.dHead != 0) r.fail("d is not a multiple of d_head");
  if (c.dHead % 4 != 0) r.fail("d_head must be a multiple of 4");
  if (c.d % c.cvDrpHeads != 0) r.fail("d is not a multiple of cv_drp_n_heads");
  if (c.d % 8 != 0) r.fail("d must be a multiple of 8 (the sin-cos codes split it in quarters)");
  if (c.patchSize != 16) r.fail("patch_size must be 16 (CV-DRP's decoder upsamples by 16)");
  if (c.imageChannels != 3 || c.rayChannels != 6) r.fail("image_channels must be 3 and ray_channels 6");
  if (c.poseTokens != 1) r.fail("pose_tokens must be 1 (the official forward asserts it)");
  if (c.imageHeight % 16 != 0 || c.imageWidth % 16 != 0) r.fail("image size must be a multiple of 16");
  if (canonical != "middle" && canonical != "first") r.fail("canonical '" + canonical + "' is not middle or first");
  c.canonicalMiddle = canonical == "middle";
  if (poseRep != "6d") r.fail("pose_representation '" + poseRep + "' is not supported by the engine (only 6d)");
  if (pluckerNorm != "none")
    r.fail("plucker_norm_mode '" + pluckerNorm + "' is not supported by the engine (only none, as spar.yaml)");
  if (c.inputMaskingMode != "soft_with_pe" && c.inputMaskingMode != "zero_out" && c.inputMaskingMode != "none")
    r.fail("input_masking_mode '" + c.inputMaskingMode + "' is not supported by the engine (soft_with_pe, zero_out, none)");
  if (!c.inputWithPe) r.fail("input_with_pe false is not supported by the engine");
  if (!(c.maskThreshold > 0.0f && c.maskThreshold < 1.0f)) r.fail("mask_threshold must be in (0, 1)");
  if (c.dino.embedDim != c.d) r.fail("dino.embed_dim must equal d (CV-DRP concatenates raw)");
  if (c.dino.patchSize != c.patchSize) r.fail("dino.patch_size must equal patch_size");
  return c;
}

}  // namespace spar
