// Elementwise unary ops (fp32) on shaders/unary.comp: activations and y = alpha * x + beta.
#pragma once
#include "engine/ops/activation.h"
#include "engine/recorder.h"

namespace spar {

enum class UnaryOp { Gelu, QuickGelu, Silu, Sigmoid, Relu, Scale };

// y = op(x) elementwise; Scale is y = alpha * x + beta (one rounding: fma), the others ignore
// alpha and beta. x, y: f32 with the same element count; y may be x itself (in place).
void unary(Recorder& rec, UnaryOp op, const Tensor& x, const Tensor& y, float alpha = 1.0f, float beta = 0.0f);

// y = act(x) with the activations of linear(); Activation::None copies (nothing in place).
void activate(Recorder& rec, Activation act, const Tensor& x, const Tensor& y);

// y = alpha * x + beta.
inline void scale(Recorder& rec, const Tensor& x, const Tensor& y, float alpha, float beta = 0.0f) {
  unary(rec, UnaryOp::Scale, x, y, alpha, beta);
}

}  // namespace spar
