// Records many dispatches, inserts the barriers their data dependencies need, and submits
// them at once. Dispatches are kept until run(), which first creates every pipeline the
// batch needs that does not exist yet (all at once, see PipelineCache::create), then writes
// the command buffer. Optionally times every dispatch with timestamp queries, keeping the
// driver's build (compile) time of a dispatch apart from its compute time.
#pragma once
#include <vulkan/vulkan.h>

#include <cstdint>
#include <algorithm>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "engine/pipeline.h"
#include "engine/tensor.h"

namespace spar {

class Engine;

// One binding of a dispatch: a tensor and how the kernel sees it (must match the
// kernel's Bind list). Texel bindings read 1 or 4 components per texel.
struct Arg {
  Tensor tensor;
  Bind kind = Bind::Read;
  int components = 1;

  static Arg in(const Tensor& t) { return {t, Bind::Read, 1}; }
  static Arg out(const Tensor& t) { return {t, Bind::Write, 1}; }
  static Arg inout(const Tensor& t) { return {t, Bind::ReadWrite, 1}; }
  static Arg texel(const Tensor& t, int components) { return {t, Bind::Texel, components}; }
};

struct DispatchTiming {
  std::string label;
  std::string stage;     // the stage set by Recorder::setStage when the dispatch was recorded
  std::string pipeline;  // the pipeline's name (kernel name, texel formats when not f32)
  double ms = 0;         // compute time of the dispatch
  double buildMs = 0;    // time the driver spent building code for it just before (0: none)
};

// What a batch of dispatches cost in commands and host waits (per stage: spar::StageTime).
struct StageCounts {
  uint64_t dispatches = 0;
  uint64_t barriers = 0;           // pipeline barriers recorded before dispatches
  uint64_t submits = 0;            // submissions the host waited for
  uint64_t transformerBlocks = 0;  // transformer blocks recorded (TransformerBlockCount)
  uint64_t blockDispatches = 0;    // the most dispatches one of them took
  StageCounts& operator+=(const StageCounts& o) {
    dispatches += o.dispatches, barriers += o.barriers, submits += o.submits, transformerBlocks += o.transformerBlocks;
    blockDispatches = std::max(blockDispatches, o.blockDispatches);
    return *this;
  }
};

class Recorder {
 public:
  explicit Recorder(Engine& engine, bool profile = false);
  ~Recorder();
  Recorder(const Recorder&) = delete;
  Recorder& operator=(const Recorder&) = delete;

  void dispatch(const Kernel& kernel, const std::vector<Arg>& args, const void* push, uint32_t pushBytes,
                uint32_t groupsX, uint32_t groupsY = 1, uint32_t groupsZ = 1, const std::string& label = "");

  template <class Push>
  void dispatch(const Kernel& kernel, const std::vector<Arg>& args, const Push& push, uint32_t gx, uint32_t gy = 1,
                uint32_t gz = 1, const std::string& label = "") {
    dispatch(kernel, args, &push, sizeof(Push), gx, gy, gz, label);
  }

  // Names the model stage the following dispatches belong to (per-stage GPU times in
  // timings(); "" for none).
  void setStage(const std::string& stage) { stage_ = stage; }
  const std::string& stage() const { return stage_; }
  // Submits everything recorded so far, waits for it, and makes results readable by the host.
  void run();

  size_t pending() const { return pending_.size(); }
  // A transformer block of `dispatches` dispatches was recorded in the current stage
  // (TransformerBlockCount, below): a stage's blocks and the most dispatches one took.
  void noteTransformerBlock(uint64_t dispatches);
  // Per stage, what the last run() submitted: dispatches, barriers, transformer blocks, and the
  // one submission it waited for (counted for the last stage of the batch).
  const std::map<std::string, StageCounts>& lastRunCounts() const { return lastCounts_; }
  // The stages of the last run()'s dispatches, in the order they were recorded.
  const std::vector<std::string>& lastRunStages() const { return lastStages_; }
  StageCounts lastRunTotal() const;
  // Barriers recorded since the last run() (dependency tracking is per buffer).
  size_t barriers() const { return barrierCount_; }
  // Per-dispatch GPU times of the last run() (empty unless profiling on a device with timestamps).
  const std::vector<DispatchTiming>& timings() const { return timings_; }
  double totalMs() const;       // compute time of the last run()
  double totalBuildMs() const;  // driver build time of the last run()

  Engine& engine() { return engine_; }

  // A buffer of `elements` floats that this recorder keeps until it is destroyed and hands to
  // every caller (its barriers order the uses, as for any buffer): for ops that stage data
  // between two of their own dispatches (conv2d's im2col patches, engine/ops/conv2d.cpp). A
  // larger request replaces it (the old one lives until its dispatches complete).
  Tensor scratch(int64_t elements);

 private:
  struct Pending {
    const Kernel* kernel = nullptr;
    std::string signature, texelState;
    VkDescriptorSet set = VK_NULL_HANDLE;
    std::vector<uint8_t> push;
    uint32_t groups[3] = {1, 1, 1};
    bool barrierBefore = false;
    std::string label, stage;
  };

  bool barrierNeeded(const std::vector<Arg>& args);
  VkDescriptorSet allocateSet(VkDescriptorSetLayout layout);
  void writeTimestamp();
  void submitPending();
  void emit(const Pending& d, const Pipeline& pipeline);
  void collectTimings(const std::vector<Pipeline*>& pipelines);
  void releaseTransient();

  Engine& engine_;
  bool profile_;
  VkCommandPool pool_ = VK_NULL_HANDLE;
  VkCommandBuffer cmd_ = VK_NULL_HANDLE;
  VkFence fence_ = VK_NULL_HANDLE;
  std::vector<Pending> pending_;
  size_t barrierCount_ = 0;
  Tensor scratch_;  // scratch()

  std::vector<VkDescriptorPool> descriptorPools_;
  size_t currentPool_ = 0;
  std::vector<VkBufferView> views_;
  // Buffers pending in the command buffer, kept alive until it completes.
  std::vector<std::shared_ptr<Buffer>> keepAlive_;

  std::set<VkBuffer> writtenSinceBarrier_, readSinceBarrier_;

  std::vector<VkQueryPool> queryPools_;
  uint32_t queriesUsed_ = 0;
  std::string stage_;
  std::vector<DispatchTiming> timings_;
  std::map<std::string, StageCounts> blocks_;  // noteTransformerBlock() since the last run(): blocks, most dispatches
  std::map<std::string, StageCounts> lastCounts_;
  std::vector<std::string> lastStages_;
};

// Counts the dispatches recorded while it lives as one transformer block of the recorder's
// stage (model/transformer_block.cpp, model/sam2_hiera_block.cpp).
class TransformerBlockCount {
 public:
  explicit TransformerBlockCount(Recorder& rec) : rec_(rec), start_(rec.pending()) {}
  ~TransformerBlockCount() { rec_.noteTransformerBlock(rec_.pending() - start_); }
  TransformerBlockCount(const TransformerBlockCount&) = delete;
  TransformerBlockCount& operator=(const TransformerBlockCount&) = delete;

 private:
  Recorder& rec_;
  size_t start_;
};

}  // namespace spar
