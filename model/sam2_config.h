// A SAM2.1 variant as the packed file's `sam2_config` metadata states it (converter/FORMAT.md,
// converter/spar_convert/sam2_config.py, whose block schedule this mirrors): the Hiera trunk's
// widths, depths, windows and global blocks, and the neck's width. The rest of the path is
// fixed by SAM2.1 (image 1024x1024, mask prompt 256x256, decoder of 2 layers, 8 heads).
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "model/sam2_hiera_block.h"

namespace spar {

struct Sam2Config {
  static constexpr int64_t kImageSize = 1024, kPatchStride = 4, kMaskInputSize = 256;

  std::string name;
  int64_t embedDim = 0, numHeads = 0, dModel = 256;
  std::vector<int64_t> stages, globalAttBlocks, windowSpec, backgroundSize, backboneChannels;

  // Parses the metadata JSON; throws one line naming the field that is missing or wrong.
  static Sam2Config fromJson(const std::string& json);

  std::vector<int64_t> stageEnds() const;       // the blocks whose outputs are the 4 stage maps
  std::vector<Sam2BlockSpec> blocks() const;    // per block: widths, heads, window, q pooling
  int64_t tokenSide() const { return kImageSize / kPatchStride; }  // 256
};

}  // namespace spar
