#include "model/stack.h"

namespace spar {

WeightLookup weightLookup(WeightSet& weights) {
  return [&weights](const std::string& name) -> Tensor {
    if (!weights.available(name)) return Tensor();
    return weights.require(name, weights.model().info(name).shape);
  };
}

std::vector<TransformerBlock> loadStack(Engine& engine, WeightSet& weights, const TransformerBlockOptions& options,
                                        const std::string& prefix, int64_t layers) {
  std::vector<TransformerBlock> blocks;
  blocks.reserve(size_t(layers));
  const WeightLookup lookup = weightLookup(weights);
  for (int64_t i = 0; i < layers; ++i) blocks.emplace_back(engine, options, lookup, prefix + "." + std::to_string(i) + ".");
  return blocks;
}

}  // namespace spar
