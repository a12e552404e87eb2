// `spar selftest --all-devices`: the self-tests of every device as one table, a column per
// device (driver), a row per check: pass or FAIL and the check's time; then each device's
// validation messages and verdict.
#pragma once
#include <vector>

#include "spar/selftest.h"

namespace spar::cli {

void printDeviceTable(const std::vector<SelftestReport>& reports);

}  // namespace spar::cli
