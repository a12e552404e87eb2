// The measured part of the kernel choice (engine/kernel_plan.h): on a GPU the best GEMM tiles,
// attention blocks and cooperative-matrix workgroup shapes depend on more than the device
// reports (register file, cache sizes, the compiler), so at first use a few candidates of each
// are timed (fp32: the four products of a transformer block of width 768 over 2048 tokens; fp16
// cooperative matrices: a 2048^3 product; attention: 8 heads of 64 over 2048 tokens) and the
// fastest kept. The choice is saved in kernel-choice.json beside
// the pipeline cache file (EngineOptions::pipelineCacheFile), keyed by device, driver and the
// shaders' SPIR-V, so later processes only read it.
#pragma once
#include <array>
#include <string>
#include <vector>

#include "engine/kernel_plan.h"

namespace spar {

class Engine;

// Sets plan.gemmTiles, attentionQueries and attentionKeys, and where the plan has cooperative
// matrices the GEMM's workgroup shape (plan.coop), from the cache file or by measuring; adds to
// plan.source and plan.reasons.
void measureKernelChoice(Engine& engine, KernelPlan& plan);

// The candidates measured (those the device's shared memory and workgroup size allow), for
// tests that check every one computes correctly.
std::vector<TiledGemmTiles> gemmTileCandidates(const DeviceCaps& caps);
std::vector<std::array<int, 3>> attentionBlockCandidates(const DeviceCaps& caps);  // queries, keys, lanes
std::vector<CoopMatTiles> coopMatTileCandidates(const DeviceCaps& caps, const CoopMatTiles& base);

// Where the choice is kept: beside the pipeline cache file, "" when there is none.
std::string kernelChoiceFile(const std::string& pipelineCacheFile);

}  // namespace spar
