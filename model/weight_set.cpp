#include "model/weight_set.h"

#include <cmath>

#include "engine/engine.h"
#include "spar/error.h"
#include "engine/half.h"
#include "model/quantized_matrices.h"

namespace spar {
namespace {

bool endsWith(const std::string& s, const std::string& tail) {
  return s.size() >= tail.size() && s.compare(s.size() - tail.size(), tail.size(), tail) == 0;
}

}  // namespace

WeightSet::WeightSet(Engine& engine, const PackedModel& model, DType matrixType)
    : engine_(engine), model_(model), matrixType_(matrixType) {
  if (matrixType != DType::F32 && matrixType != DType::F16 && !isQuantized(matrixType))
    throw Error(std::string("weight matrices can be f32, f16, q8 or q4, not ") + dtypeName(matrixType));
  // fp16 matrices reach the kernels as fp16 texel buffers or as halves in the words of a
  // storage input: refused up front where neither is possible (Engine::readsFp16Inputs).
  if (matrixType == DType::F16 && !engine.readsFp16Inputs())
    throw Error("fp16 weights need fp16 texel buffers or storage-buffer inputs, which " + engine.caps().name +
                (engine.caps().limitsProfile.empty() ? "" : " under device-limit profile " + engine.caps().limitsProfile) +
                " lacks: use fp32 weights");
}

bool WeightSet::isMatrix(const std::string& name, const Shape& shape) {
  if (shape.size() < 2 || endsWith(name, "view_type_embedding.weight")) return false;
  // SAM2's learned decoder tokens (iou, mask, object-score) are embeddings, not matrices
  if (name.rfind("sam2.", 0) == 0 && (endsWith(name, "_token.weight") || endsWith(name, "_tokens.weight")))
    return false;
  return endsWith(name, ".weight") || endsWith(name, "in_proj_weight") || endsWith(name, "text_projection");
}

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
  return require(name, shape, uploadType(name));
}

DType WeightSet::uploadType(const std::string& name) const {
  if (!model_.has(name)) throw Error(model_.errorPrefix() + "tensor '" + name + "' is missing");
  const bool matrix = isMatrix(name, model_.info(name).shape);
  DType want = model_.naturalDType(name);
  // Matrices follow the requested precision whatever the file stores: an F16 file's matrices
  // are widened under F32, so an fp32 run uses only the f32 kernel variants (each extra
  // variant costs seconds of shader JIT on lavapipe) and computes with the same values.
  // A quantized matrix stays quantized under every type (the GEMM dequantizes it). Under Q8 / Q4
  // the matrices the converter would quantize are quantized at upload, the others stay f32.
  if (matrix && !isQuantized(want)) {
    if (!isQuantized(matrixType_)) want = matrixType_;
    else if (isQuantizedMatrix(name, model_.info(name).shape)) want = matrixType_;
    else want = DType::F32;
  }
  return want;
}

void WeightSet::roundToHalf(const std::string& name, std::vector<float>& v) const {
  // As `spar-convert --fp16` does: a value fp16 cannot hold refuses, it is not saturated.
  for (float& x : v) {
    if (!(std::abs(x) <= 65504.0f))
      throw Error(model_.errorPrefix() + "tensor '" + name + "' has the value " + std::to_string(x) +
                  ", beyond float16's range: run it with f32 weights");
    x = halfToFloat(floatToHalf(x));
  }
}

Tensor WeightSet::uploadRounded(const std::string& name, DType want) const {
  std::vector<float> v = model_.floats(name);
  roundToHalf(name, v);
  return engine_.fromFloats(model_.info(name).shape, v, want);
}

const Tensor& WeightSet::require(const std::string& name, const Shape& shape, DType want) {
  checkShape(name, shape);
  auto key = std::make_pair(name, want);
  if (auto it = loaded_.find(key); it != loaded_.end()) {
    if (padded_.count(key))
      throw Error("weight '" + name + "' is on the device padded to " + shapeString(it->second.shape()) +
                  "; asked for as stored too");
    return it->second;
  }
  const PackedTensorInfo& info = model_.info(name);
  const bool rounded = matrixType_ == DType::F16 && info.dtype == FileDType::F32 && isMatrix(name, info.shape) &&
                       (want == DType::F32 || want == DType::F16);
  Tensor t;
  if (isQuantized(want) && !info.quantBits) {  // an f32 / f16 file's matrix quantized here
    checkQuantizable(name, want);
    const Shape matrix = quantizedMatrixShape(info.shape);  // a conv kernel as [Cout, Cin*kh*kw]
    const std::vector<uint8_t> rows = quantizeRows(model_.floats(name), matrix[0], matrix[1], want);
    t = engine_.tensor(matrix, want);
    engine_.write(t, rows.data(), rows.size());
  } else {
    t = rounded ? uploadRounded(name, want) : model_.upload(engine_, name, want);
  }
  return keep(std::move(key), std::move(t));
}

DType WeightSet::matrixType(Precision precision) {
  switch (precision) {
    case Precision::FP16: return DType::F16;
    case Precision::Q8: return DType::Q8;
    case Precision::Q4: return DType::Q4;
    case Precision::FP32: break;
  }
  return DType::F32;
}

void WeightSet::checkQuantizable(const std::string& name, DType want) const {
  if (!isQuantizedMatrix(name, model_.info(name).shape))
    throw Error(model_.errorPrefix() + "tensor '" + name + "' is not a matrix the " + dtypeName(want) +
                " rule quantizes (converter/FORMAT.md, Quantized matrices)");
}

Tensor WeightSet::requirePadded(const std::string& name, const Shape& shape, const Shape& paddedShape) {
  checkShape(name, shape);
  const DType want = uploadType(name);
  if (isQuantized(want)) return {};
  const Shape& stored = model_.info(name).shape;
  bool ok = paddedShape.size() == stored.size() && !stored.empty();
  for (size_t i = 0; ok && i < stored.size(); ++i) ok = paddedShape[i] >= stored[i];
  if (!ok)
    throw Error("weight '" + name + "' " + shapeString(stored) + " cannot be padded to " + shapeString(paddedShape));
  auto key = std::make_pair(name, want);
  if (auto it = loaded_.find(key); it != loaded_.end()) {
    if (!padded_.count(key) || it->second.shape() != paddedShape)
      throw Error("weight '" + name + "' is on the device as " + shapeString(it->second.shape()) + "; asked for padded to " +
                  shapeString(paddedShape) + " too");
    return it->second;
  }
  // The values require would upload (fp16-rounded under matrixType F16), placed in a zero tensor
  // of the padded shape a row of the last dimension at a time: stored row r's multi-index over
  // the leading dimensions, then that index's row in the padded tensor.
  std::vector<float> v = model_.floats(name);
  if (matrixType_ == DType::F16 && isMatrix(name, stored)) roundToHalf(name, v);
  const int64_t cols = stored.back();
  std::vector<float> padded(static_cast<size_t>(shapeNumel(paddedShape)), 0.0f);
  for (int64_t r = 0, rows = cols > 0 ? int64_t(v.size()) / cols : 0; r < rows; ++r) {
    int64_t rest = r, row = 0, rowsBelow = 1;
    for (size_t d = stored.size() - 1; d-- > 0;) {
      row += (rest % stored[d]) * rowsBelow;
      rest /= stored[d];
      rowsBelow *= paddedShape[d];
    }
    std::copy(v.begin() + r * cols, v.begin() + (r + 1) * cols, padded.begin() + row * paddedShape.back());
  }
  padded_.insert(key);
  return keep(std::move(key), engine_.fromFloats(paddedShape, padded, want));
}

const Tensor& WeightSet::keep(std::pair<std::string, DType> key, Tensor t) {
  bytes_ += t.bytes();
  order_.push_back(key);
  return loaded_.emplace(std::move(key), std::move(t)).first->second;
}

Tensor WeightSet::optional(const std::string& name, const Shape& shape) {
  if (!model_.has(name)) return {};
  return require(name, shape);
}

const Tensor& WeightSet::loadedTensor(const std::string& name, DType dtype) const {
  auto it = loaded_.find({name, dtype});
  if (it == loaded_.end()) throw Error("weight '" + name + "' was not loaded as " + dtypeName(dtype));
  return it->second;
}

void WeightSet::clear() {
  loaded_.clear();
  order_.clear();
  bytes_ = 0;
}

}  // namespace spar
