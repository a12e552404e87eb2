// Specialization constants frozen into a SPIR-V module, for drivers that optimize a shader
// only as far as its constants are constants. SwiftShader applies a pipeline's specialization
// by changing the constants' defaults, so its SPIR-V optimizer still sees them as specialization
// constants: a loop bounded by one is never unrolled and an array sized by one stays in
// memory, where every access is a per-lane load or store. Handed the same module with the
// values as plain constants it unrolls and keeps the arrays in registers (spar-bench's
// multiply-add chains: 0.8 -> 47 GFLOPS; docs/portability.md). KernelPlan::freezeConstants
// says where (engine/kernel_plan.h); engine/pipeline.cpp applies it. Host-side only: the
// values are the ones the pipeline would have been specialized with, so the kernel computes
// the same thing.
#pragma once
#include <cstdint>
#include <span>
#include <utility>
#include <vector>

namespace spar {

// `module` with every OpSpecConstant / OpSpecConstantTrue / OpSpecConstantFalse made a plain
// constant: of the 32-bit value `values` gives its SpecId (a bool is true when nonzero), or its
// default where `values` has none. Their SpecId decorations are dropped; composites and
// operations of specialization constants stay (a driver folds those itself). Throws Error for
// a module that is not SPIR-V or a 64-bit specialization constant given a value.
std::vector<uint32_t> freezeSpecConstants(std::span<const uint32_t> module,
                                          const std::vector<std::pair<uint32_t, uint32_t>>& values);

}  // namespace spar
