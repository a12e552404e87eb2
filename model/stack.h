// A stack of SPAR transformer blocks read from the packed file by its official prefix
// ("transformer_encoder", "transformer_encoder_geom", "transformer_decoder",
// "cv_drp.estimator.transformer_layers"): blocks <prefix>.0 ... <prefix>.<layers-1>.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "model/transformer_block.h"
#include "model/weight_set.h"

namespace spar {

// The WeightLookup of a WeightSet: each tensor uploaded on first use in its stored dtype, with
// the shape the file declares (the block checks shapes against its options).
WeightLookup weightLookup(WeightSet& weights);

std::vector<TransformerBlock> loadStack(Engine& engine, WeightSet& weights, const TransformerBlockOptions& options,
                                        const std::string& prefix, int64_t layers);

}  // namespace spar
