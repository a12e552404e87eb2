// The weights a request actually uses, uploaded from a PackedModel on first use and kept by
// name: a stage asks for each tensor it reads with require(), so a tensor no stage asks for
// never reaches the device. bytesLoaded() / loaded() say what was uploaded (the "leave out
// what a scene does not need" reports).
//
// Weight precision: with matrixType F16 every weight matrix (the tensors `spar-convert --fp16`
// stores as F16, converter/FORMAT.md) reaches the device with fp16 values even when the file
// holds F32, so one F32 file serves both precisions and gives what its --fp16 pack would. With
// Q8 / Q4 the matrices `--weights q8 / q4` quantizes are quantized at upload (the rest as f32),
// as that pack holds them; a quantized file's matrices stay quantized under every type.
#pragma once
#include <cstdint>
#include <map>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "engine/tensor.h"
#include "model/packed_model.h"
#include "spar/precision.h"

namespace spar {

class Engine;

class WeightSet {
 public:
  // The model must outlive the set. matrixType F32: matrices as f32 (an F16 file's widened);
  // F16: matrices as fp16 (norms, biases, tokens and codes are never touched); Q8 / Q4: see above.
  WeightSet(Engine& engine, const PackedModel& model, DType matrixType = DType::F32);

  const PackedModel& model() const { return model_; }
  bool available(const std::string& name) const { return model_.has(name); }

  // The tensor `name` on the device, uploaded on first use. `shape` is what the caller
  // expects (a dimension of -1 matches any size). Uploaded in the stored dtype (I64 as i32),
  // a matrix as F16 under matrixType F16.
  // Throws one line naming the tensor when it is missing or shaped differently.
  const Tensor& require(const std::string& name, const Shape& shape);
  // The dtype require(name, shape) uploads `name` in (throws if the file lacks it). A quantized
  // convolution kernel [Cout, Cin, kh, kw] arrives as its matrix [Cout, Cin*kh*kw].
  DType uploadType(const std::string& name) const;
  // Same, in a given dtype (F32 <-> F16 converted; see PackedModel::upload). Under matrixType
  // F16 a matrix asked for as F32 (an op that reads only f32) holds the fp16-rounded values.
  const Tensor& require(const std::string& name, const Shape& shape, DType want);
  // Same as require when the file has the tensor; an undefined Tensor when it has not.
  Tensor optional(const std::string& name, const Shape& shape);
  // `name` (of `shape`, checked as require does) on the device with zeros appended up to
  // paddedShape, no dimension smaller than the file's and the rank the same, in the dtype
  // require would give it; undefined where that dtype is quantized (its rows are blocks of 32).
  // Only the padded tensor reaches the device; asking for a tensor both padded and as stored
  // throws. For layouts a layer chooses itself (engine/ops/row_padding.h).
  Tensor requirePadded(const std::string& name, const Shape& shape, const Shape& paddedShape);

  // Drops every uploaded tensor (the device memory returns once no Tensor copy holds it).
  void clear();

  DType matrixType() const { return matrixType_; }
  // The matrix type of a precision (spar/precision.h): F32, F16, Q8, Q4.
  static DType matrixType(Precision precision);
  // The --fp16 rule (converter/spar_convert/convert.py is_matrix): a float tensor of 2 or more
  // dimensions named *.weight / *in_proj_weight / *text_projection, except the view-type table
  // and SAM2's decoder tokens (sam2.*_token(s).weight).
  static bool isMatrix(const std::string& name, const Shape& shape);

  size_t count() const { return loaded_.size(); }
  uint64_t bytesLoaded() const { return bytes_; }
  // An uploaded tensor (throws if `name` was not loaded in `dtype`).
  const Tensor& loadedTensor(const std::string& name, DType dtype) const;
  // Names (with the dtype they were uploaded in) in the order they were loaded.
  const std::vector<std::pair<std::string, DType>>& loaded() const { return order_; }

 private:
  void checkShape(const std::string& name, const Shape& shape) const;
  // Throws unless `name` is a matrix the q8 / q4 rule quantizes (model/quantized_matrices.h).
  void checkQuantizable(const std::string& name, DType want) const;
  // Records an uploaded tensor under `key` (counted in bytesLoaded(), listed in loaded()).
  const Tensor& keep(std::pair<std::string, DType> key, Tensor t);
  // Rounds an F32 file's matrix values to fp16 ones (throws for one beyond fp16's range).
  void roundToHalf(const std::string& name, std::vector<float>& v) const;
  // An F32 file's matrix with fp16 values, in `want` (matrixType F16 only).
  Tensor uploadRounded(const std::string& name, DType want) const;

  Engine& engine_;
  const PackedModel& model_;
  DType matrixType_;
  std::map<std::pair<std::string, DType>, Tensor> loaded_;
  std::set<std::pair<std::string, DType>> padded_;  // the loaded_ entries requirePadded made
  std::vector<std::pair<std::string, DType>> order_;
  uint64_t bytes_ = 0;
};

}  // namespace spar
