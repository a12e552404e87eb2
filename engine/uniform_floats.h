// Uniform and normal random floats for test and benchmark inputs (tests/, the self-test's checks,
// spar-bench's cases): the numbers std::uniform_real_distribution<float> and
// std::normal_distribution<float> give with libstdc++, bit for bit, without their cost under Clang.
//
// libstdc++'s generate_canonical takes the log2 of the generator's range with a long-double
// std::log on every draw. GCC folds that into a constant; Clang (the build's compiler,
// scripts/setup/build.sh) calls logl twice a draw: measured, 3.7x test_linear's whole time.
// Its arithmetic for float and std::mt19937 (32-bit draws) is one draw over 2^32, kept below 1,
// then scaled; the normal one is Marsaglia's polar method on two such draws, the second value of
// a pair kept for the next call: written out here, so every seeded input stays what it was.
#pragma once

#include <cmath>
#include <random>

namespace spar {

inline float uniformFloat(std::mt19937& rng, float lo, float hi) {
  float canonical = static_cast<float>(rng()) / 4294967296.0f;
  if (canonical >= 1.0f) canonical = std::nextafter(1.0f, 0.0f);
  return canonical * (hi - lo) + lo;
}

// std::normal_distribution<float>(mean, stddev) drawn from one generator: one object per sequence.
class NormalFloats {
 public:
  NormalFloats(float mean, float stddev) : mean_(mean), stddev_(stddev) {}
  float operator()(std::mt19937& rng) {
    float value;
    if (saved_) {
      saved_ = false;
      value = savedValue_;
    } else {
      float x, y, r2;
      do {
        // float times float, then minus a double, as libstdc++ writes it
        x = 2.0f * uniformFloat(rng, 0.0f, 1.0f) - 1.0;
        y = 2.0f * uniformFloat(rng, 0.0f, 1.0f) - 1.0;
        r2 = x * x + y * y;
      } while (r2 > 1.0 || r2 == 0.0);
      const float mult = std::sqrt(-2 * std::log(r2) / r2);
      savedValue_ = x * mult;
      saved_ = true;
      value = y * mult;
    }
    return value * stddev_ + mean_;
  }

 private:
  float mean_, stddev_;
  bool saved_ = false;
  float savedValue_ = 0.0f;
};

}  // namespace spar
