// The op checks of the self-test (include/spar/selftest.h): one op family each, on odd sizes and
// stiff values, against a float64 reference computed here on the host from the same fp32 inputs.
#pragma once
#include <functional>
#include <string>
#include <vector>

#include "engine/engine.h"
#include "spar/selftest.h"

namespace spar::selftest {

// `got` against float64 `want` into c: NMSE, max abs error, finiteness (the op checks and the
// self-test model's stages measure alike).
void measureAgainst(SelftestCheck& c, const std::vector<float>& got, const std::vector<double>& want);

// Runs every check on `engine` (each in its own recorder, in order).
std::vector<SelftestCheck> runSelftestChecks(Engine& engine);

}  // namespace spar::selftest
