#include "model/stack.h"

namespace spar {

WeightLookup weightLookup(WeightSet& weights) {
  WeightLookup lookup = [&weights](const std::string& name) -> Tensor {
    if (!weights.available(name)) return Tensor();
    return weights.require(name, weights.model().info(name).shape);
  };
  lookup.padded = [&weights](const std::string& name, const Shape& paddedShape) -> Tensor {
    if (!weights.available(name)) return Tensor();
    return weights.requirePadded(name, weights.model().info(name).shape, paddedShape);
  };
  return lookup;
}

WeightLookup weightLookup(WeightSet& weights, WeightLocator locate) {
  WeightLookup lookup = [&weights, locate](const std::string& name) -> Tensor {
    const auto [key, shape] = locate(name);
    return weights.require(key, shape);
  };
  lookup.padded = [&weights, locate](const std::string& name, const Shape& paddedShape) -> Tensor {
    const auto [key, shape] = locate(name);
    return weights.requirePadded(key, shape, paddedShape);
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
