// Uniform random floats for test and benchmark inputs (tests/, the self-test's checks,
// spar-bench's cases): the numbers std::uniform_real_distribution<float> gives with libstdc++, bit
// for bit, without its cost under Clang.
//
// libstdc++'s generate_canonical takes the log2 of the generator's range with a long-double
// std::log on every draw. GCC folds that into a constant; Clang (the build's compiler,
// scripts/setup/build.sh) calls logl twice a draw: measured, 3.7x test_linear's whole time.
// Its arithmetic for float and std::mt19937 (32-bit draws) is one draw over 2^32, kept below 1,
// then scaled: written out here, so every seeded input stays what it was.
#pragma once

#include <cmath>
#include <random>

namespace spar {

inline float uniformFloat(std::mt19937& rng, float lo, float hi) {
  float canonical = static_cast<float>(rng()) / 4294967296.0f;
  if (canonical >= 1.0f) canonical = std::nextafter(1.0f, 0.0f);
  return canonical * (hi - lo) + lo;
}

}  // namespace spar
