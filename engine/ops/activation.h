#pragma once
namespace spar {
// Matches the ACT_* codes in shaders/common.glsl.
enum class Activation : int { None = 0, Gelu = 1, QuickGelu = 2, Silu = 3, Sigmoid = 4, Relu = 5 };
}  // namespace spar
