// The measured part of the kernel choice (engine/kernel_plan.h): on a GPU the best GEMM tiles
// depend on more than the device reports (register file, cache sizes, the compiler), so at
// first use a few candidates are timed on one product and the fastest kept. The choice is
// saved in kernel-choice.json beside the pipeline cache file (EngineOptions::pipelineCacheFile),
// keyed by device, driver and the GEMM shader's SPIR-V, so later processes only read it.
#pragma once
#include <string>

#include "engine/kernel_plan.h"

namespace spar {

class Engine;

// Sets plan.gemmTiles (and plan.source, a reason) from the cache file or by measuring.
void chooseGemmTilesByMeasurement(Engine& engine, KernelPlan& plan);

// Where the choice is kept: beside the pipeline cache file, "" when there is none.
std::string kernelChoiceFile(const std::string& pipelineCacheFile);

}  // namespace spar
