// A SAM2.1 variant as the packed file's `sam2_config` metadata states it (converter/FORMAT.md,
// converter/spar_convert/sam2_config.py, whose block schedule this mirrors): the Hiera trunk's
// widths, depths, windows and global blocks, the neck's width and the image side (1024 in every
// official variant; smaller in test models: the trunk's maps, the image embedding and the mask
// prompt follow it). The rest of the path is fixed by SAM2.1 (decoder of 2 layers, 8 heads).
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "model/sam2_hiera_block.h"

namespace spar {

struct Sam2Config {
  static constexpr int64_t kPatchStride = 4;

  std::string name;
  int64_t embedDim = 0, numHeads = 0, dModel = 256;
  int64_t imageSize = 1024;  // the encoder's input side, a multiple of 32 (four stages of 2x)
  std::vector<int64_t> stages, globalAttBlocks, windowSpec, backgroundSize, backboneChannels;

  // Parses the metadata JSON; throws one line naming the field that is missing or wrong.
  static Sam2Config fromJson(const std::string& json);

  std::vector<int64_t> stageEnds() const;       // the blocks whose outputs are the 4 stage maps
  std::vector<Sam2BlockSpec> blocks() const;    // per block: widths, heads, window, q pooling
  int64_t tokenSide() const { return imageSize / kPatchStride; }      // 256 at 1024
  int64_t maskInputSize() const { return imageSize / kPatchStride; }  // the mask prompt's side: 4 x the embedding's
};

}  // namespace spar
