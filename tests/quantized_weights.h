// Block-quantized weights for the kernel tests (engine/tensor.h DType::Q8 / Q4), made here
// independently of the converter (converter/spar_convert/quantize.py) and of the engine's
// upload-time quantizer (model/quantized_matrices.h): per block of 32 along a row, scale =
// max|w| / Q (127 or 7) rounded to f32, code = round(w / scale). Each row's codes, then its
// scales, as PackedModel::upload lays them out.
#pragma once
#include <cstdint>
#include <vector>

#include "engine/engine.h"

namespace spar::test {

struct QuantizedMatrix {
  std::vector<uint8_t> rows;  // the device layout
  std::vector<float> values;  // code * scale in f32, what a kernel multiplies with
};

QuantizedMatrix quantizeReference(const std::vector<float>& w, int64_t N, int64_t K, int bits);
// The matrix [N, K] on the device as Q8 (bits 8) or Q4.
Tensor quantizedTensor(Engine& engine, const QuantizedMatrix& m, int64_t N, int64_t K, int bits);
// Rows of 32 * blocks values with the stiff blocks of the kernels' quantized tests (and of
// spar selftest's): block 0 one outlier of +-1e4 among values of 1e-2, block 1 all zeros,
// block 2 values whose scale is float's smallest normal; the rest values of 1e-2.
std::vector<float> stiffQuantizedRows(int64_t N, int64_t K, uint32_t seed);

}  // namespace spar::test
