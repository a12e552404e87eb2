// Row widths a CPU's L1 cache aliases, and the width a layout the model chooses itself gets
// instead (KernelPlan::padAliasedRows).
//
// An L1 data cache of 4 KiB ways (x86's, most ARM cores' at least as large) indexes its sets by
// the address bits below 4096, so rows whose length is a multiple of 4096 bytes all fall in one
// set. gemm.comp's shared-columns block reads 32 rows of x and 32 of w at once along k: with
// 3072 floats a row (the official model's MLP hidden) 64 rows compete for one set's 12 ways and
// every fetch goes to L2. llvmpipe, 2056 x 3072 x 768: 79-83 GFLOPS against 108-118 with rows of
// 3076 floats; 1024^3: 87 against 124 with rows of 1028 (2048-byte multiples, two sets, lose
// 10-15 %; other rows under 3 %).
#pragma once
#include <cstdint>

#include "engine/kernel_plan.h"

namespace spar::ops {

// Zeros a widened row ends in: 4 keeps a multiple of 4 a multiple of 4 (RGBA texels).
constexpr int64_t kRowPadding = 4;

// The row length for `elements` fp32 values a layer lays out itself: elements, or elements +
// kRowPadding where the plan pads and the row is a multiple of 2048 bytes. Padding is exact for
// a GEMM's k dimension: the added weight columns are zero and the added inputs finite.
inline int64_t unaliasedRow(const KernelPlan& plan, int64_t elements) {
  return plan.padAliasedRows && elements > 0 && (elements * 4) % 2048 == 0 ? elements + kRowPadding : elements;
}

}  // namespace spar::ops
