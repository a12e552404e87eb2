// SPIR-V compiled from shaders/*.comp at build time (cmake/EmbedShaders.cmake), one entry
// per variant named in the shader's "//! variant" lines.
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

const std::vector<EmbeddedShader>& embeddedShaders();  // generated

// The SPIR-V of a variant; throws Error for an unknown name.
std::span<const uint32_t> findShader(const std::string& name);

}  // namespace spar
