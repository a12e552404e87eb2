// Device memory: what a request needs, known before any work (Session::estimateMemory), and what
// the engine has used (Context::memory). The estimate is made from the same list of stages the
// request runs (docs/architecture.md), so it covers every stage that can run.
#pragma once
#include <cstdint>
#include <string>

namespace spar {

// What a session will be asked for beyond encoding, for the estimate.
struct RenderUse {
  int64_t viewsPerCall = -1;  // views one render call renders at once (-1: the request's targets)
  int64_t labelPrompts = 0;   // prompts label maps will be asked for (0: no label maps)
};

struct MemoryEstimate {
  uint64_t minBytes = 0;         // the least the request needs: its weights and the activations it keeps
  uint64_t maxBytes = 0;         // the most its peak can reach (a request within it does not run out)
  uint64_t weightBytes = 0;      // of minBytes: the weights of the stages the request runs
  uint64_t activationBytes = 0;  // of minBytes: the rest
  uint64_t budgetBytes = 0;      // what the engine may use on this device (0: no limit known)
  std::string budgetSource;      // where the budget comes from, e.g. "the device's heap"
  int64_t maxInputViews = 0;     // input views that surely fit the budget at this image size
  // One line each, "" when there is nothing to say: why the request cannot run ("this request
  // needs at least N MiB of device memory (...), more than the M MiB available (...)"), and
  // why it may run out midway (maxBytes above the budget).
  std::string refusal;
  std::string warning;
};

// What the engine's device memory went through so far.
struct MemoryStats {
  uint64_t bytesInUse = 0;
  uint64_t peakBytes = 0;
  uint64_t budgetBytes = 0;  // as MemoryEstimate::budgetBytes
  std::string budgetSource;
  uint64_t allocations = 0;  // device buffers allocated
  uint64_t submissions = 0;  // command buffers submitted
};

}  // namespace spar
