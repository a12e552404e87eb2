// SPIR-V compiled at build time (cmake/EmbedShaders.cmake), one entry per variant named in a
// shader's "//! variant" lines. The engine's general ops (shaders/) are always there; code
// outside the engine with kernels of its own (SPAR's, in model/shaders/) registers its set
// before it asks for them.
#pragma once
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace spar {

struct EmbeddedShader {
  const char* name;
  const uint32_t* words;
  size_t wordCount;
};

const std::vector<EmbeddedShader>& engineShaders();  // generated from shaders/

// Adds a set (its table must live as long as the program; registering it again is a no-op).
// Thread-safe.
void registerShaders(const std::vector<EmbeddedShader>& set);

// The SPIR-V of a variant from the engine's or a registered set; throws Error for an unknown
// name.
std::span<const uint32_t> findShader(const std::string& name);

}  // namespace spar
