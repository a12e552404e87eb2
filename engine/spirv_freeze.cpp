#include "engine/spirv_freeze.h"

#include <string>
#include <unordered_map>

#include "spar/error.h"

namespace spar {
namespace {

// The few opcodes and the decoration this needs (SPIR-V specification, 3.32 and 3.20).
constexpr uint32_t kMagic = 0x07230203;
constexpr uint32_t kOpDecorate = 71;
constexpr uint32_t kOpConstantTrue = 41, kOpConstantFalse = 42, kOpConstant = 43;
constexpr uint32_t kOpSpecConstantTrue = 48, kOpSpecConstantFalse = 49, kOpSpecConstant = 50;
constexpr uint32_t kDecorationSpecId = 1;
constexpr size_t kHeaderWords = 5;

uint32_t opcode(uint32_t word) { return word & 0xFFFFu; }
uint32_t wordCount(uint32_t word) { return word >> 16; }

}  // namespace

std::vector<uint32_t> freezeSpecConstants(std::span<const uint32_t> module,
                                          const std::vector<std::pair<uint32_t, uint32_t>>& values) {
  if (module.size() < kHeaderWords || module[0] != kMagic) throw Error("freezeSpecConstants: not a SPIR-V module");
  // Pass 1: which result ids carry which SpecId.
  std::unordered_map<uint32_t, uint32_t> specIdOf;  // result id -> SpecId
  for (size_t i = kHeaderWords; i < module.size();) {
    const uint32_t n = wordCount(module[i]);
    if (n == 0 || i + n > module.size()) throw Error("freezeSpecConstants: truncated instruction at word " + std::to_string(i));
    if (opcode(module[i]) == kOpDecorate && n == 4 && module[i + 2] == kDecorationSpecId) specIdOf[module[i + 1]] = module[i + 3];
    i += n;
  }
  std::unordered_map<uint32_t, uint32_t> valueOf(values.begin(), values.end());  // SpecId -> value

  // Pass 2: copy, dropping the SpecId decorations and rewriting the constants.
  std::vector<uint32_t> out(module.begin(), module.begin() + kHeaderWords);
  out.reserve(module.size());
  for (size_t i = kHeaderWords; i < module.size();) {
    const uint32_t n = wordCount(module[i]), op = opcode(module[i]);
    const auto word = [&](size_t k) { return module[i + k]; };
    if (op == kOpDecorate && n == 4 && word(2) == kDecorationSpecId) {
      i += n;
      continue;
    }
    if (op == kOpSpecConstantTrue || op == kOpSpecConstantFalse) {  // result type, result id
      bool value = op == kOpSpecConstantTrue;
      if (auto s = specIdOf.find(word(2)); s != specIdOf.end())
        if (auto v = valueOf.find(s->second); v != valueOf.end()) value = v->second != 0;
      out.insert(out.end(), {(n << 16) | (value ? kOpConstantTrue : kOpConstantFalse), word(1), word(2)});
      i += n;
      continue;
    }
    if (op == kOpSpecConstant) {  // result type, result id, the default's words
      out.push_back((n << 16) | kOpConstant);
      out.insert(out.end(), module.begin() + i + 1, module.begin() + i + n);
      if (auto s = specIdOf.find(word(2)); s != specIdOf.end())
        if (auto v = valueOf.find(s->second); v != valueOf.end()) {
          if (n != 4) throw Error("freezeSpecConstants: SpecId " + std::to_string(s->second) + " is not a 32-bit constant");
          out.back() = v->second;
        }
      i += n;
      continue;
    }
    out.insert(out.end(), module.begin() + i, module.begin() + i + n);
    i += n;
  }
  return out;
}

}  // namespace spar
