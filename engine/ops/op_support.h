// Small helpers every op's host code uses (engine/ops/*.cpp).
#pragma once
#include <cstdint>
#include <string>

#include "spar/error.h"
#include "engine/tensor.h"

namespace spar::ops {

// Workgroups needed for `a` items at `b` per workgroup.
inline uint64_t ceilDiv(uint64_t a, uint64_t b) { return (a + b - 1) / b; }

inline void requireF32(const Tensor& t, const std::string& op, const char* what) {
  if (!t.defined()) throw Error(op + ": " + what + " tensor is missing");
  if (t.dtype() != DType::F32) throw Error(op + ": " + what + " must be f32, got " + t.describe());
}

}  // namespace spar::ops
