// A stack of SPAR transformer blocks read from the packed file by its official prefix
// ("transformer_encoder", "transformer_encoder_geom", "transformer_decoder",
// "cv_drp.estimator.transformer_layers"): blocks <prefix>.0 ... <prefix>.<layers-1>.
#pragma once
#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "model/transformer_block.h"
#include "model/weight_set.h"

namespace spar {

// The WeightLookup of a WeightSet: each tensor uploaded on first use in its stored dtype, with
// the shape the file declares (the block checks shapes against its options); padded on request
// (WeightSet::requirePadded).
WeightLookup weightLookup(WeightSet& weights);

// Where a block's weight lives in a model whose names differ from the block's (DINOv3's, timm's,
// CLIP's): the file's key and the shape it must have; an empty key (or a throw) for a name the
// model lacks.
using WeightLocator = std::function<std::pair<std::string, Shape>(const std::string& blockName)>;
// The WeightLookup of a WeightSet through a locator: require() of the located tensor, and
// requirePadded() for the padded lookup.
WeightLookup weightLookup(WeightSet& weights, WeightLocator locate);

std::vector<TransformerBlock> loadStack(Engine& engine, WeightSet& weights, const TransformerBlockOptions& options,
                                        const std::string& prefix, int64_t layers);

}  // namespace spar
