// How the engine is set up: which Vulkan device, validation, caches, diagnostics, and tile
// overrides for tuning. Every field has a working default; fromEnvironment() is one way to fill
// the struct (what the command-line tools use), a program may set the fields itself.
#pragma once
#include <array>
#include <optional>
#include <string>

#include "spar/device_limits.h"
#include "spar/export.h"

namespace spar {

// Overrides of the engine's per-device kernel choices, for tuning with spar-bench and for
// running one device's kernels on another (tests). Unset: the engine chooses per device.
struct SPAR_API KernelTuning {
  std::optional<std::array<int, 5>> gemmTiles;           // RM, RN, LX, LY, KU
  std::optional<std::array<int, 3>> attentionTiles;      // queries per invocation, keys per block, LX
  std::optional<std::array<int, 5>> convTiles;           // RC, RY, RX, LX, LY
  std::optional<std::array<int, 5>> convTransposeTiles;  // RC, RY, RX, LX, LY
  std::optional<std::array<int, 3>> lineGroup;           // SPLIT (0|1), LX (multiple of 8), LY

  // The kernel family, forced (SPAR_KERNELS): "" lets the engine choose per device;
  // "cpu": register blocks through texel buffers, no shared memory (what llvmpipe rewards);
  // "gpu": shared-memory tiles and subgroup reductions; "gpu-fp16": "gpu", and GEMMs with
  // fp16 weights compute in fp16 (fp32 accumulation); "coopmat": "gpu", and GEMMs with fp16
  // weights run on VK_KHR_cooperative_matrix (an error on a device without it).
  std::string kernels;
  // How kernels read their inputs, forced (SPAR_INPUTS): "" lets the engine choose per device
  // (storage buffers where texel buffers are shorter than a storage binding); "texel": texel
  // buffers; "storage": storage buffers of 32-bit words (the *_sx kernels), as on such a device.
  std::string inputs;
  // GPU GEMM tiles (SPAR_GPU_GEMM_TILES): BM, BN, BK, TM, TN, and PIPELINED (1: the next k step
  // fetched while one computes, register blocks interleaved; 0: one step at a time)
  std::optional<std::array<int, 6>> gpuGemmTiles;
  // GPU attention: queries a workgroup, keys a block, and LANES, the invocations sharing each 4
  // queries (attention_flash.comp); LANES 0: one query an invocation (attention_tiled.comp).
  std::optional<std::array<int, 3>> gpuAttentionTiles;
  // gemm_coopmat.comp: MMAs per subgroup WM x WN, subgroups SG_M x SG_N, K blocks a step
  // (SPAR_COOPMAT_TILES=WM,WN,SGM,SGN,KSTEPS,PIPELINED,PIPELINED; PIPELINED 1: the next step fetched while
  // one multiplies)
  std::optional<std::array<int, 6>> coopMatTiles;
  // Measure the GPU tile candidates (GEMM, attention, cooperative matrices) at first use
  // (SPAR_MEASURE_KERNELS=1 / 0); unset: on GPUs only; off when any tile above is forced. The choice is kept in kernel-choice.json beside the pipeline cache file.
  std::optional<bool> measureKernels;
  // Write the specialization constants' values into each module instead of specializing it
  // (SPAR_FREEZE_CONSTANTS=1 / 0); unset: where the driver needs it to optimize (SwiftShader;
  // engine/spirv_freeze.h).
  std::optional<bool> freezeConstants;
  // The CPU family's GEMMs of fp32 weights with a subgroup's lanes splitting k (gemm_lanes.comp;
  // SPAR_GEMM_LANES=1 / 0); unset: SwiftShader's plan. Needs subgroup arithmetic and full subgroups.
  std::optional<bool> gemmLanesSplitK;
  // The CPU family's attention of fp32 q, k and v with a subgroup's lanes splitting the head
  // dimension (attention_lanes.comp; SPAR_ATTENTION_LANES=1 / 0); unset: SwiftShader's plan.
  // Needs subgroup arithmetic and full subgroups.
  std::optional<bool> attentionLanesSplitDim;
  // The hidden rows of transformer MLPs (and their weights) widened by 4 zeros where a row is a
  // multiple of 2048 bytes (SPAR_ROW_PADDING=1 / 0); unset: where the CPU family runs gemm.comp's
  // register blocks (engine/ops/row_padding.h).
  std::optional<bool> padAliasedRows;
  // The CPU family's gemm.comp: workgroups go through the columns in groups of this many blocks
  // of rows (SPAR_GEMM_ROW_GROUPS=N, 0: in the order dispatched; at most 4096); unset: 8.
  std::optional<int> gemmRowGroups;

  // Throws Error (one line, naming the field) for a value no kernel can take.
  void validate() const;
};

// Test hooks: make the N-th device buffer allocation fail as if the device were out of memory,
// or the N-th submission's wait report a timeout (counting from 1 in this engine; 0: never), so
// tests can check that each failure path gives one error line, writes nothing and leaks no
// Vulkan object. The submission's work is completed before its timeout is reported.
struct SPAR_API FaultInjection {
  unsigned long long allocation = 0;
  unsigned long long submission = 0;
};

struct SPAR_API EngineOptions {
  // Which device: an index ("0") or a case-insensitive part of its name ("llvmpipe"). Empty:
  // the first discrete, integrated, virtual, then CPU device.
  std::string device;
  bool validation = false;   // VK_LAYER_KHRONOS_validation, its messages counted and printed
  bool verbose = false;      // print the chosen device and features to stderr
  // Where the driver's pipeline cache is kept across runs ("" keeps none).
  std::string pipelineCacheFile;
  bool logPipelines = false;  // every pipeline's creation and driver build on stderr
  bool profileDispatches = false;  // every dispatch's GPU time on stderr (model stages)
  KernelTuning tuning;
  // How long one submission may run before the engine gives up on the device (an error saying
  // so instead of a program that hangs with the GPU), in milliseconds; 0: no limit. After such a
  // timeout the device's state is unknown: destroy the engine and exit.
  unsigned long long submitTimeoutMs = 600000;
  // At most this many bytes of device memory in use at once (0: the device's own heap size):
  // a request that needs more is refused (before work where its need is known up front, else as
  // an out-of-memory error), as on a device with that much memory.
  unsigned long long memoryLimitBytes = 0;
  // Act as if the device had at most these limits and features (a named profile such as
  // "vulkan-1.2-min", or a JSON file's: include/spar/device_limits.h). Empty: the device's own.
  DeviceLimits limits;
  FaultInjection faults;

  // `base` with what the environment sets: SPAR_DEVICE, SPAR_VALIDATION=1, SPAR_LOG_PIPELINES=1,
  // SPAR_PROFILE=1, SPAR_GEMM_TILES=RM,RN,LX,LY,KU, SPAR_ATTENTION_TILES=QPI,KB,LX,
  // SPAR_CONV_TILES / SPAR_CONVT_TILES=RC,RY,RX,LX,LY, SPAR_LINE_GROUP=SPLIT,LX,LY,
  // SPAR_KERNELS=cpu|gpu|gpu-fp16|coopmat, SPAR_INPUTS=texel|storage, SPAR_GPU_GEMM_TILES=BM,BN,BK,TM,TN,PIPELINED,
  // SPAR_GPU_ATTENTION_TILES=QUERIES,KEYS,LANES, SPAR_COOPMAT_TILES=WM,WN,SGM,SGN,KSTEPS,
  // SPAR_MEASURE_KERNELS=0|1,
  // SPAR_SUBMIT_TIMEOUT_MS, SPAR_MEMORY_LIMIT_MB, SPAR_DEVICE_LIMITS=PROFILE|FILE.json, SPAR_FAULT_ALLOCATION=N, SPAR_FAULT_SUBMISSION=N. A field
  // already set in `base` (device non-empty) wins over the environment. Throws Error for a
  // malformed value, naming the variable.
  static EngineOptions fromEnvironment(EngineOptions base);
  static EngineOptions fromEnvironment();
  // The pipeline cache file the command-line tools use, and beside it kernel-choice.json (the
  // measured kernel choice): $XDG_CACHE_HOME/spar/pipelines.bin, else ~/.cache/spar/pipelines.bin
  // (the directory is made); "" when SPAR_PIPELINE_CACHE=0, neither variable is set, or the
  // directory cannot be made.
  static std::string defaultPipelineCacheFile();
};

}  // namespace spar
