#include "model/stack.h"

namespace spar {

WeightLookup weightLookup(WeightSet& weights) {
  // the block's names are the file's; a name the file lacks finds nothing (the block says which)
  return weightLookup(weights, [&weights](const std::string& name) -> std::pair<std::string, Shape> {
    if (!weights.available(name)) return {};
    return {name, weights.model().info(name).shape};
  });
}

WeightLookup weightLookup(WeightSet& weights, WeightLocator locate) {
  WeightLookup lookup = [&weights, locate](const std::string& name) -> Tensor {
    const auto [key, shape] = locate(name);
    return key.empty() ? Tensor() : weights.require(key, shape);
  };
  lookup.padded = [&weights, locate](const std::string& name, const Shape& paddedShape) -> Tensor {
    const auto [key, shape] = locate(name);
    return key.empty() ? Tensor() : weights.requirePadded(key, shape, paddedShape);
  };
  return lookup;
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
