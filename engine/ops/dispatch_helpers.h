// Shared by the elementwise and line-reduction ops (unary, binary, copy2d, norm,
// reduce_channels): workgroup grids inside the device's limits, row chunks inside one
// storage binding, workgroup shapes for line reductions (shaders/line_reduce.glsl), and
// checks for tensors that share memory.
#pragma once
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <initializer_list>
#include <numeric>
#include <string>
#include <utility>
#include <vector>

#include "engine/engine.h"
#include "spar/error.h"
#include "engine/ops/op_support.h"

namespace spar::ops {

// Workgroups as a 2-D grid when one dimension cannot hold them all. Shaders recover the
// linear workgroup index as gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x and
// ignore indices past the count (the last grid row may be partly filled).
struct Grid {
  uint32_t x = 0, y = 1;
};
inline Grid linearGrid(const DeviceCaps& caps, uint64_t groups, const std::string& op) {
  if (groups == 0) return {0, 1};
  const uint64_t x = std::min<uint64_t>(groups, caps.maxWorkGroupCount[0]);
  const uint64_t y = ceilDiv(groups, x);
  if (y > caps.maxWorkGroupCount[1])
    throw Error(op + ": " + std::to_string(groups) + " workgroups exceed the device's grid");
  return {static_cast<uint32_t>(x), static_cast<uint32_t>(y)};
}

// Consecutive row ranges (first row, row count) such that each tensor, bound from the first
// row of a range on with the given bytes per row, fits one storage binding and starts at an
// offset the device can bind (if the whole tensor does). Ranges start at multiples of
// rowMultiple. One range when everything fits.
inline std::vector<std::pair<int64_t, int64_t>> rowChunks(Engine& engine, int64_t rows,
                                                          std::initializer_list<uint64_t> bytesPerRow,
                                                          const std::string& op, uint64_t rowMultiple = 1) {
  const uint64_t limit = engine.device().bindingRangeLimit();
  const uint64_t align = std::max<uint64_t>(1, engine.caps().minStorageBufferOffsetAlignment);
  uint64_t chunk = static_cast<uint64_t>(rows), step = std::max<uint64_t>(1, rowMultiple);
  for (uint64_t b : bytesPerRow) {
    if (b == 0) continue;
    chunk = std::min(chunk, limit / b);
    step = std::lcm(step, align / std::gcd(b, align));  // rows whose bytes are a multiple of align
  }
  std::vector<std::pair<int64_t, int64_t>> out;
  if (rows <= 0) return out;
  if (chunk < static_cast<uint64_t>(rows)) chunk = chunk / step * step;
  if (chunk == 0) throw Error(op + ": one row exceeds the device's storage binding range");
  for (int64_t r = 0; r < rows; r += static_cast<int64_t>(chunk))
    out.emplace_back(r, std::min<int64_t>(static_cast<int64_t>(chunk), rows - r));
  return out;
}

// Byte ranges of two tensors intersect / are the same range of the same buffer.
inline bool overlaps(const Tensor& a, const Tensor& b) {
  if (!a.defined() || !b.defined() || a.bufferPtr() != b.bufferPtr()) return false;
  return a.byteOffset() < b.byteOffset() + b.bytes() && b.byteOffset() < a.byteOffset() + a.bytes();
}
inline bool sameMemory(const Tensor& a, const Tensor& b) {
  return a.defined() && b.defined() && a.bufferPtr() == b.bufferPtr() && a.byteOffset() == b.byteOffset() &&
         a.bytes() == b.bytes();
}

// Elementwise kernels (unary, binary, copy2d, ...): workgroups of 256 invocations, or the
// device's limit when it is lower (128 is all Vulkan guarantees), each invocation handling one
// vec4 of 4 consecutive values (llvmpipe loads a vec4 for about the cost of a float).
inline int elementLocalX(const DeviceCaps& caps) {
  return static_cast<int>(std::clamp<uint32_t>(caps.maxWorkGroupInvocations / 8 * 8, 8, 256));
}
inline uint64_t elementsPerGroup(const DeviceCaps& caps) { return 4 * uint64_t(elementLocalX(caps)); }

// Workgroup shape for shaders/line_reduce.glsl. split: the lanes along x share one line;
// otherwise every invocation owns a line.
struct LineGroup {
  bool split = true;
  int localX = 8, localY = 1;
  // The *_sg shader variants: split lines, one a workgroup, reduced with subgroup operations.
  bool subgroup = false;
  uint64_t linesPerGroup() const { return split ? uint64_t(localY) : uint64_t(localX) * localY; }
};
// lineLength counts the units a kernel loads (vec4s or values); contiguous: a line's values
// are adjacent in memory (rows), not strided (NCHW channels).
// CPU shapes (the plan's, engine/kernel_plan.h; lavapipe): an invocation per line unless lines are long and too few to keep the
// cores busy (splitting costs barriers, which are coroutine switches there: LayerNorm of
// 4096 x 1024 took ~10 ms unsplit, ~15 ms split). GPU: long contiguous lines are split so that
// neighbouring invocations read neighbouring addresses; with the plan's subgroup reductions a
// split line is a workgroup of its own, reduced by the *_sg variants.
// EngineOptions::tuning.lineGroup (SPAR_LINE_GROUP="SPLIT,LX,LY", SPLIT 0 or 1) overrides the choice, for tuning and for
// testing the GPU shapes on a CPU device.
inline LineGroup lineGroupFor(Engine& engine, int64_t lineLength, bool contiguous, int64_t lines) {
  const DeviceCaps& caps = engine.caps();
  const KernelTuning& tuning = engine.options().tuning;
  const bool subgroups = engine.plan().subgroupReductions;
  if (const auto& t = tuning.lineGroup) return {(*t)[0] == 1, (*t)[1], (*t)[2], subgroups && (*t)[0] == 1 && (*t)[2] == 1};
  const int simd = std::max(8, static_cast<int>((caps.subgroupSize + 7) / 8 * 8));
  if (engine.plan().cpuShapes) {
    const bool split = lineLength >= 32 && lines < 512;
    return {split, simd, split ? 1 : 8};
  }
  const bool split = lineLength >= 32 && (contiguous || lines < 4096);
  if (!split) return {false, std::max(simd, 64), 1};
  int lanes = simd;
  while (lanes < 64 && lanes < lineLength) lanes *= 2;
  // With subgroup reductions a workgroup is one line (see line_reduce.glsl, SUBGROUP).
  if (subgroups) return {true, lanes, 1, true};
  return {true, lanes, std::max(1, std::min(256, elementLocalX(caps)) / lanes)};
}



}  // namespace spar::ops
