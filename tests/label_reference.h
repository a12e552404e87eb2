// The official label map in float64, for the tests' comparisons (model/label_maps.h on the
// engine): LSeg's output_conv (the logits x2, bilinear, align_corners=True, PyTorch's formula)
// and the argmax over the prompts (the first maximum).
#pragma once
#include <cstdint>
#include <vector>

namespace spar::test {

// logits [R, P, h, w] -> [R, P, 2h, 2w].
std::vector<double> upsampledLogits(const std::vector<double>& logits, int64_t R, int64_t P, int64_t h, int64_t w);
// scores [R, P, n] -> [R, n], the first maximum.
std::vector<int64_t> firstArgmax(const std::vector<double>& scores, int64_t R, int64_t P, int64_t n);

}  // namespace spar::test
