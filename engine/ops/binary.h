// Elementwise add and multiply with broadcasting (fp32) on shaders/binary.comp.
#pragma once
#include "engine/recorder.h"

namespace spar {

enum class BinaryOp { Add, Mul };

// out = a + b and out = a * b. b with a's element count meets a element by element; otherwise
// b is broadcast to a's shape by NumPy rules: b's dimensions align
// with a's trailing ones and each is 1 or equal to a's, and the ones equal to a's (other than
// 1) must be consecutive: same shape, a bias per column ([R, C] with [C]), a value per channel
// ([N, C, H, W] with [C, 1, 1]), or a value per row ([R, C] with [R, 1]). out: a's element
// count; may be a itself (in place), or b when b has a's shape.
void add(Recorder& rec, const Tensor& a, const Tensor& b, const Tensor& out);
void mul(Recorder& rec, const Tensor& a, const Tensor& b, const Tensor& out);

// The explicit form: element i of a meets b[(i / bInner) % b.numel()].
void binary(Recorder& rec, BinaryOp op, const Tensor& a, const Tensor& b, const Tensor& out, int64_t bInner);

}  // namespace spar
