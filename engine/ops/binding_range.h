// Helpers shared by the image ops (patchify, conv2d, conv_transpose2d, resize, pool):
// binding any element range of a tensor, and splitting a dispatch into chunks whose
// bindings fit the device's limits. No shader of its own.
#pragma once
#include <algorithm>
#include <cstdint>
#include <string>

#include "engine/engine.h"
#include "spar/error.h"
#include "engine/ops/copy2d.h"
#include "engine/recorder.h"
#include "engine/ops/op_support.h"

namespace spar::ops {

// A binding that covers elements [begin, end) of t. The view starts where the device
// allows a binding to start (at or before begin, possibly before t's first element);
// a kernel reads or writes element i of t as element (i - base) of the binding.
struct BoundRange {
  Tensor view;
  int32_t base = 0;
};

// Where a binding may start, in bytes. A texel input may be bound as a storage buffer
// instead (KernelPlan::storageInputs), so its start satisfies both alignments (powers of two:
// the larger is a multiple of the smaller).
inline uint64_t bindingAlignment(const DeviceCaps& caps, bool texel) {
  const uint64_t storage = caps.minStorageBufferOffsetAlignment;
  return std::max<uint64_t>(4, texel ? std::max<uint64_t>(caps.minTexelBufferOffsetAlignment, storage) : storage);
}

// Largest slack, in elements, that aligning a binding's start adds.
inline int64_t alignmentSlack(const DeviceCaps& caps, bool texel) {
  return static_cast<int64_t>(bindingAlignment(caps, texel) / 4);
}

// t itself where the device can bind it from its first element, else (fp32) a copy of it in a
// tensor of its own, recorded on rec: a view into the middle of an activation (one view's
// tokens past a class token) may start where a device with 256-byte alignment cannot bind.
inline Tensor alignedInput(Recorder& rec, const Tensor& t, bool texel) {
  if (!t.defined() || t.dtype() != DType::F32 || t.byteOffset() % bindingAlignment(rec.engine().caps(), texel) == 0)
    return t;
  Tensor copy = rec.engine().tensor(t.shape(), t.dtype());
  const int64_t n = t.numel();
  copy2d(rec, t.reshape({n}), n, 0, copy.reshape({n}), n, 0, 1, n);
  return copy;
}

inline BoundRange bindRange(const DeviceCaps& caps, const Tensor& t, int64_t begin, int64_t end, bool texel) {
  const uint64_t align = bindingAlignment(caps, texel);
  if (t.byteOffset() % 4) throw Error("tensor " + t.describe() + " is not 4-byte aligned");
  const uint64_t beginByte = t.byteOffset() + static_cast<uint64_t>(begin) * 4;
  const uint64_t startByte = beginByte / align * align;
  BoundRange r;
  r.base = static_cast<int32_t>((static_cast<int64_t>(startByte) - static_cast<int64_t>(t.byteOffset())) / 4);
  const int64_t count = end - r.base;
  r.view = Tensor(t.bufferPtr(), startByte, {count}, t.dtype());
  return r;
}

// Elements one binding may cover: storage buffers by the device's range, texel buffers by
// their element count.
// (texel inputs bound as storage buffers, KernelPlan::storageInputs, by the storage range).
inline int64_t bindingElements(Engine& engine, bool texel) {
  return texel && !engine.plan().storageInputs
             ? static_cast<int64_t>(std::min<uint64_t>(engine.caps().maxTexelBufferElements, INT32_MAX))
             : static_cast<int64_t>(std::min<uint64_t>(engine.device().bindingRangeLimit() / 4, INT32_MAX));
}

// Texels of `components` floats one texel input may hold (bound as a texel buffer, or as a
// storage buffer of floats where the plan says so).
inline uint64_t texelInputLimit(Engine& engine, int components) {
  return engine.plan().storageInputs ? engine.device().bindingRangeLimit() / (4 * uint64_t(components))
                                     : engine.caps().maxTexelBufferElements;
}

// Largest number of work units per dispatch such that `units` units of `perUnit` elements
// each (plus the alignment slack and `extra` elements) fit one binding; throws if not even one does.
inline int64_t unitsPerBinding(Engine& engine, bool texel, int64_t perUnit, int64_t extra, const std::string& what) {
  const int64_t room = bindingElements(engine, texel) - alignmentSlack(engine.caps(), texel) - extra;
  if (perUnit <= 0) return INT32_MAX;
  if (room < perUnit) throw Error(what + " is too large for one binding on this device");
  return room / perUnit;
}

// Splits an image op into dispatches whose bindings fit the device. Work units are
// (image, block of blockChannels output channels) pairs; unit u is image u / blocks, block
// u % blocks, with blocks = ceil(channels / blockChannels). The input x holds `images`
// equal parts read whole by their units; the output y is [images, channels, outPlane].
// fn(u0, u1, in, out) records one dispatch for units [u0, u1), with in and out binding
// the elements those units read and write; each unit takes zPerUnit workgroup layers.
struct UnitChunk {
  int64_t u0, u1;
  BoundRange in, out;
};
template <class Fn>
void forEachUnitChunk(Engine& engine, const Tensor& x, const Tensor& y, int64_t images, int64_t channels,
                      int64_t blockChannels, int64_t outPlane, int64_t zPerUnit, const std::string& op, Fn&& fn) {
  const DeviceCaps& caps = engine.caps();
  const int64_t blocks = (channels + blockChannels - 1) / blockChannels;
  const int64_t units = images * blocks, inPerImage = x.numel() / images;
  const int64_t maxUnits =
      std::min<int64_t>(caps.maxWorkGroupCount[2] / zPerUnit,
                        unitsPerBinding(engine, false, blockChannels * outPlane, 0, op + ": output of one work unit"));
  const int64_t maxImages = unitsPerBinding(engine, true, inPerImage, 0, op + ": input of one image");
  if (maxUnits < 1) throw Error(op + ": too many workgroups for one unit");
  for (int64_t u0 = 0; u0 < units;) {
    const int64_t n0 = u0 / blocks;
    const int64_t u1 = std::min({units, u0 + maxUnits, (n0 + maxImages) * blocks});
    const int64_t n1 = (u1 - 1) / blocks + 1;
    const int64_t outBegin = (n0 * channels + (u0 - n0 * blocks) * blockChannels) * outPlane;
    const int64_t outEnd = ((n1 - 1) * channels + std::min(channels, (u1 - (n1 - 1) * blocks) * blockChannels)) * outPlane;
    fn(UnitChunk{u0, u1, bindRange(caps, x, n0 * inPerImage, n1 * inPerImage, true),
                 bindRange(caps, y, outBegin, outEnd, false)});
    u0 = u1;
  }
}

inline void checkElementCount(const Tensor& t, const char* op) {
  if (t.numel() >= INT32_MAX) throw Error(std::string(op) + ": " + t.describe() + " has too many elements for 32-bit indexing");
}

}  // namespace spar::ops
