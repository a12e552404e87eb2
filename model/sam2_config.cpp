// A SAM2.1 variant (model/sam2_config.h).
#include "model/sam2_config.h"

#include <algorithm>

#include <nlohmann/json.hpp>

#include "spar/error.h"

namespace spar {
namespace {

std::vector<int64_t> ints(const nlohmann::json& j, const char* key, size_t n) {
  if (!j.contains(key) || !j[key].is_array()) throw Error(std::string("sam2_config: no list ") + key);
  std::vector<int64_t> v;
  for (const auto& e : j[key]) {
    if (!e.is_number_integer()) throw Error(std::string("sam2_config: ") + key + " holds a non-integer");
    v.push_back(e.get<int64_t>());
  }
  if (n && v.size() != n) throw Error(std::string("sam2_config: ") + key + " must have " + std::to_string(n) + " entries");
  return v;
}

// At most `limit`: every official variant is far inside (hiera_l: embed_dim 144, 36 blocks in
// stage 3, windows of 16), and the block schedule, the widths' doublings and the buffers sized
// from them stay small and free of overflow.
int64_t positive(const nlohmann::json& j, const char* key, int64_t limit) {
  if (!j.contains(key) || !j[key].is_number_integer() || j[key].get<int64_t>() <= 0 || j[key].get<int64_t>() > limit)
    throw Error(std::string("sam2_config: ") + key + " must be an integer in 1.." + std::to_string(limit));
  return j[key].get<int64_t>();
}

void within(const std::vector<int64_t>& v, const char* key, int64_t lo, int64_t limit) {
  for (int64_t x : v)
    if (x < lo || x > limit)
      throw Error(std::string("sam2_config: ") + key + " entries must be in " + std::to_string(lo) + ".." +
                  std::to_string(limit));
}

}  // namespace

Sam2Config Sam2Config::fromJson(const std::string& text) {
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(text);
  } catch (const nlohmann::json::exception& e) {
    throw Error(std::string("sam2_config is not valid JSON: ") + e.what());
  }
  if (!j.is_object()) throw Error("sam2_config is not a JSON object");
  Sam2Config c;
  c.name = j.value("name", std::string("sam2"));
  c.embedDim = positive(j, "embed_dim", 1024);
  c.numHeads = positive(j, "num_heads", 64);
  c.dModel = positive(j, "d_model", 2048);
  // absent in files packed before it was recorded: those are official variants, all at 1024
  c.imageSize = j.contains("image_size") ? positive(j, "image_size", 2048) : 1024;
  if (c.imageSize % 32 || c.imageSize < 64) throw Error("sam2_config: image_size must be a multiple of 32, at least 64");
  c.stages = ints(j, "stages", 4);
  c.globalAttBlocks = ints(j, "global_att_blocks", 0);
  c.windowSpec = ints(j, "window_spec", 4);
  c.backgroundSize = ints(j, "window_pos_embed_bkg_spatial_size", 2);
  c.backboneChannels = ints(j, "backbone_channel_list", 4);
  within(c.stages, "stages", 1, 256);
  within(c.windowSpec, "window_spec", 1, c.tokenSide());
  within(c.backgroundSize, "window_pos_embed_bkg_spatial_size", 1, c.tokenSide());
  within(c.globalAttBlocks, "global_att_blocks", 0, 4 * 256);
  if (c.embedDim % c.numHeads) throw Error("sam2_config: embed_dim is not a multiple of num_heads");
  for (size_t i = 0; i < 4; ++i)
    if (c.backboneChannels[i] != c.embedDim << (3 - i))
      throw Error("sam2_config: backbone_channel_list does not match the trunk's stage widths");
  if (c.tokenSide() % c.windowSpec[0]) throw Error("sam2_config: window_spec[0] does not tile the token map");
  for (const Sam2BlockSpec& b : c.blocks()) {
    if (b.qPool && b.window % 2) throw Error("sam2_config: a q-pooling block has an odd window");
    if ((b.dimOut / b.heads) % 4) throw Error("sam2_config: Hiera heads must have a multiple of 4 channels");
  }
  // the decoder's cross-attention: 8 heads of d_model / 16 channels, a multiple of 4
  if (c.dModel % 64) throw Error("sam2_config: d_model must be a multiple of 64");
  return c;
}

std::vector<int64_t> Sam2Config::stageEnds() const {
  std::vector<int64_t> ends;
  int64_t sum = 0;
  for (int64_t s : stages) ends.push_back((sum += s) - 1);
  return ends;
}

std::vector<Sam2BlockSpec> Sam2Config::blocks() const {
  // hieradet.Hiera.__init__: dims and heads x2 at the first block of stages 2-4, which also
  // pools q; the window lags a block (that block still has the previous stage's window)
  const std::vector<int64_t> ends = stageEnds();
  std::vector<Sam2BlockSpec> out;
  int64_t dim = embedDim, heads = numHeads;
  size_t stage = 0;
  for (int64_t i = 0; i < ends.back() + 1; ++i) {
    Sam2BlockSpec b;
    b.dim = dim;
    b.window = std::count(globalAttBlocks.begin(), globalAttBlocks.end(), i) ? 0 : windowSpec[stage];
    b.dimOut = dim;
    if (std::count(ends.begin(), ends.end(), i - 1)) {
      b.dimOut = dim * 2;
      heads *= 2;
      ++stage;
      b.qPool = true;
    }
    b.heads = heads;
    out.push_back(b);
    dim = b.dimOut;
  }
  return out;
}

}  // namespace spar
