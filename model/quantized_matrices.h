// Block quantization of weight matrices at upload (converter/FORMAT.md, "Quantized matrices"):
// which matrices `spar-convert --weights q8 / q4` quantizes, and the same quantization of an
// fp32 file's matrix on the host, so that one fp32 file runs at every precision and gives what
// its q8 / q4 pack would (tests/test_spar_precision.cpp compares them).
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "engine/tensor.h"

namespace spar {

// The converter's rule (QUANTIZED_MATRICES in converter/spar_convert/convert.py): the linear
// layers of the transformer blocks and SPAR's other linear layers but the RGB head, CLIP's
// token embedding (engine/ops/embedding.h reads it quantized) and LSeg's larger convolutions
// (engine/ops/conv2d.h reads them quantized); 2-D, or a 4-D kernel, with rows of whole blocks of 32.
bool isQuantizedMatrix(const std::string& name, const Shape& shape);

// The matrix [N, K] a quantized tensor of `shape` is on the device: [N, K] itself, or a
// convolution kernel [Cout, Cin, kh, kw] as [Cout, Cin*kh*kw].
Shape quantizedMatrixShape(const Shape& shape);

// Rows of codes then scales (engine/tensor.h DType::Q8 / Q4) of the row-major [N, K] matrix
// `w`, K a multiple of 32: per block scale = max|w| / 127 (q8) or / 7 (q4) rounded to float32,
// code = round(w / scale), as converter/spar_convert/quantize.py does.
std::vector<uint8_t> quantizeRows(const std::vector<float>& w, int64_t N, int64_t K, DType type);

}  // namespace spar
