// The precision of the weight matrices on the device (SessionOptions::precision, `--precision`).
// Activations and accumulation are fp32 in every precision; norms, biases and learned tokens
// stay fp32. What each costs in error and time: docs/benchmarks.md (spar-modes).
#pragma once
#include <string>
#include <vector>

#include "spar/export.h"

namespace spar {

enum class Precision {
  FP32,  // as the file stores them (fp16 in a `spar-convert --fp16` pack)
  FP16,  // fp16 on the device: half the memory; needs 16-bit storage
  Q8,    // 8-bit codes with a float32 scale per 32 (converter/FORMAT.md): 0.28 of fp32
  Q4,    // 4-bit codes likewise: 0.16 of fp32
};

// "fp32", "fp16", "q8", "q4".
SPAR_API std::string precisionName(Precision precision);
// The precision of a name above; throws spar::Error listing the names for any other.
SPAR_API Precision parsePrecision(const std::string& name);
// The names, in the order above.
SPAR_API std::vector<std::string> precisionNames();

}  // namespace spar
