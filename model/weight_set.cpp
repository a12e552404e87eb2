#include "model/weight_set.h"

#include "engine/engine.h"
#include "engine/error.h"

namespace spar {

WeightSet::WeightSet(Engine& engine, const PackedModel& model) : engine_(engine), model_(model) {}

void WeightSet::checkShape(const std::string& name, const Shape& shape) const {
  if (!model_.has(name)) throw Error(model_.errorPrefix() + "tensor '" + name + "' is missing (expected " + shapeString(shape) + ")");
  const Shape& actual = model_.info(name).shape;
  bool ok = actual.size() == shape.size();
  for (size_t i = 0; ok && i < shape.size(); ++i) ok = shape[i] == -1 || shape[i] == actual[i];
  if (!ok)
    throw Error(model_.errorPrefix() + "tensor '" + name + "' has shape " + shapeString(actual) + ", expected " +
                shapeString(shape));
}

const Tensor& WeightSet::require(const std::string& name, const Shape& shape) {
  checkShape(name, shape);
  return require(name, shape, model_.naturalDType(name));
}

const Tensor& WeightSet::require(const std::string& name, const Shape& shape, DType want) {
  checkShape(name, shape);
  auto key = std::make_pair(name, want);
  if (auto it = loaded_.find(key); it != loaded_.end()) return it->second;
  Tensor t = model_.upload(engine_, name, want);
  bytes_ += t.bytes();
  order_.push_back(key);
  return loaded_.emplace(std::move(key), std::move(t)).first->second;
}

Tensor WeightSet::optional(const std::string& name, const Shape& shape) {
  if (!model_.has(name)) return {};
  return require(name, shape);
}

void WeightSet::clear() {
  loaded_.clear();
  order_.clear();
  bytes_ = 0;
}

}  // namespace spar
