// The "kernels" entry of report.json / result.json: every pipeline the run made, what creating
// it cost, how often the driver built code for it at a dispatch (compiles, or reloads from the
// driver's cache) and why, and its compute time; with totals first.
#pragma once
#include <nlohmann/json.hpp>

#include "engine/engine.h"

namespace spar::cli {

nlohmann::ordered_json kernelReport(const Engine& engine);

}  // namespace spar::cli
