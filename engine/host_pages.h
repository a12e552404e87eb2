// Huge pages for the host memory behind a CPU device's buffers (engine/memory.cpp). On a CPU
// Vulkan driver (lavapipe, SwiftShader) device memory is ordinary process memory that the
// driver maps once and the first touch faults in page by page; asking the kernel for
// transparent huge pages on it, before the engine writes it, takes 512 times fewer faults
// (measured on this project's VM: the full-size model test 55 -> 43 s). Only a hint: where the
// kernel has no transparent huge pages, or the range is a GPU's mapping, nothing changes.
#pragma once
#include <cstddef>

namespace spar {

// madvise(MADV_HUGEPAGE) on the whole 2 MiB-aligned pages inside [data, data + bytes);
// false where nothing was advised (a range under 2 MiB, no Linux, or the kernel refused).
bool adviseHugePages(void* data, size_t bytes);

}  // namespace spar
