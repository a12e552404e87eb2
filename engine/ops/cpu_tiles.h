// Which of the measured tile tables a CPU device gets. The register blocks of the kernels
// (gemm, attention, conv2d, conv_transpose2d) trade run time against how long the driver
// takes to compile each variant, and llvmpipe generations differ in both (docs/first-run-and-kernels.md, "Kernel
// choice per device"):
//   Wide    16 lanes (llvmpipe built for 512-bit vectors): the big blocks every CPU got before
//           these tables, measured fastest on an earlier AVX-512 machine; not re-measured
//           (no 16-lane device here).
//   Mesa22  8 lanes, Mesa 22.3: texel fetches are inline gathers; mid-size blocks run as fast
//           as big ones and compile 4-10x faster.
//   Newer   8 lanes, Mesa after 22 (measured on 25.0.7): texel fetches call separately
//           compiled functions, every block runs at about the same speed and compiles 3-6x
//           slower than on 22.3, so the smallest blocks that keep the speed.
// Other CPU implementations get the Mesa22 table.
#pragma once
#include <algorithm>

#include "engine/device.h"

namespace spar::ops {

enum class CpuTiles { Wide, Mesa22, Newer };

inline CpuTiles cpuTiles(const DeviceCaps& caps) {
  if (caps.subgroupSize > 8) return CpuTiles::Wide;
  if (caps.isLlvmpipe() && caps.mesaMajor > 22) return CpuTiles::Newer;
  return CpuTiles::Mesa22;
}

// Invocations along x share one SIMD vector on llvmpipe: a multiple of the lane count.
inline int cpuLanes(const DeviceCaps& caps) { return std::max<int>(8, static_cast<int>(caps.subgroupSize)); }

// Whether a workgroup can be one subgroup whose lanes share the texels all of them read (the
// GEMM's columns, attention's keys: shaders/gemm.comp SHARED_COLUMNS, shaders/attention.comp
// SHARED_KEYS), each lane fetching its part and shuffling the rest from the others. Measured on
// llvmpipe only (docs/first-run-and-kernels.md), where a texel fetch is a call that spills the
// accumulators; it needs subgroup shuffles and full subgroups of the lane count.
inline bool cpuLanesShareFetches(const DeviceCaps& caps) {
  return caps.isLlvmpipe() && caps.subgroupShuffle && caps.fullSubgroups && int(caps.subgroupSize) == cpuLanes(caps);
}

}  // namespace spar::ops
