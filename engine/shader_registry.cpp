#include "engine/shader_registry.h"

#include "engine/error.h"

namespace spar {

std::span<const uint32_t> findShader(const std::string& name) {
  for (const auto& s : embeddedShaders())
    if (name == s.name) return {s.words, s.wordCount};
  throw Error("no embedded shader named '" + name + "'");
}

}  // namespace spar
