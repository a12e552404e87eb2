#include "engine/shader_registry.h"

#include <algorithm>
#include <mutex>

#include "spar/error.h"

namespace spar {
namespace {

std::mutex& registryMutex() {
  static std::mutex m;
  return m;
}
std::vector<const std::vector<EmbeddedShader>*>& registeredSets() {
  static std::vector<const std::vector<EmbeddedShader>*> sets;
  return sets;
}

}  // namespace

void registerShaders(const std::vector<EmbeddedShader>& set) {
  std::lock_guard lock(registryMutex());
  auto& sets = registeredSets();
  if (std::find(sets.begin(), sets.end(), &set) == sets.end()) sets.push_back(&set);
}

std::span<const uint32_t> findShader(const std::string& name) {
  for (const auto& s : engineShaders())
    if (name == s.name) return {s.words, s.wordCount};
  std::lock_guard lock(registryMutex());
  for (const auto* set : registeredSets())
    for (const auto& s : *set)
      if (name == s.name) return {s.words, s.wordCount};
  throw Error("no embedded shader named '" + name + "'");
}

}  // namespace spar
