// The "kernels" entry of report.json / result.json (spar/kernel_report.h as JSON): every pipeline
// the run made, what creating it cost, how often the driver built code for it at a dispatch
// (compiles, or reloads from the driver's cache) and why, and its compute time; totals first.
#pragma once
#include <nlohmann/json.hpp>

#include "spar/kernel_report.h"

namespace spar::cli {

nlohmann::ordered_json kernelReportJson(const KernelReport& report);

}  // namespace spar::cli
