// The weights a request actually uses, uploaded from a PackedModel on first use and kept by
// name: a stage asks for each tensor it reads with require(), so a tensor no stage asks for
// never reaches the device. bytesLoaded() / loaded() say what was uploaded (the "leave out
// what a scene does not need" reports).
#pragma once
#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "engine/tensor.h"
#include "model/packed_model.h"

namespace spar {

class Engine;

class WeightSet {
 public:
  // The model must outlive the set.
  WeightSet(Engine& engine, const PackedModel& model);

  const PackedModel& model() const { return model_; }
  bool available(const std::string& name) const { return model_.has(name); }

  // The tensor `name` on the device, uploaded on first use. `shape` is what the caller
  // expects (a dimension of -1 matches any size). Uploaded in the stored dtype (I64 as i32).
  // Throws one line naming the tensor when it is missing or shaped differently.
  const Tensor& require(const std::string& name, const Shape& shape);
  // Same, in a given dtype (F32 <-> F16 converted; see PackedModel::upload).
  const Tensor& require(const std::string& name, const Shape& shape, DType want);
  // Same as require when the file has the tensor; an undefined Tensor when it has not.
  Tensor optional(const std::string& name, const Shape& shape);

  // Drops every uploaded tensor (the device memory returns once no Tensor copy holds it).
  void clear();

  size_t count() const { return loaded_.size(); }
  uint64_t bytesLoaded() const { return bytes_; }
  // Names (with the dtype they were uploaded in) in the order they were loaded.
  const std::vector<std::pair<std::string, DType>>& loaded() const { return order_; }

 private:
  void checkShape(const std::string& name, const Shape& shape) const;

  Engine& engine_;
  const PackedModel& model_;
  std::map<std::pair<std::string, DType>, Tensor> loaded_;
  std::vector<std::pair<std::string, DType>> order_;
  uint64_t bytes_ = 0;
};

}  // namespace spar
