// Which family of kernels each op runs on a device, with which tiles, and why. Chosen once per
// engine from the device's properties (type, subgroup operations, fp16 arithmetic,
// cooperative-matrix sizes) and the tuning overrides; on GPUs the GEMM tiles may then be
// measured at first use (engine/kernel_tuner.h). `spar-bench --list-kernels` prints it.
#pragma once
#include <string>
#include <vector>

#include "engine/device.h"
#include "spar/engine_options.h"

namespace spar {

enum class KernelFamily {
  CpuBlocks,  // register blocks through texel buffers, no shared memory (gemm.comp, ...): llvmpipe
  Tiled,      // workgroup tiles in shared memory (gemm_tiled.comp, attention_tiled.comp): GPUs
  CoopMat,    // VK_KHR_cooperative_matrix, fp16 in, fp32 accumulation (gemm_coopmat.comp)
};
const char* familyName(KernelFamily family);

// gemm_tiled.comp: a workgroup computes BM x BN outputs per BK step, an invocation TM x TN.
// pipelined: the next k step fetched while this one computes, register blocks interleaved
// (PREFETCH, INTERLEAVE); off, the kernel as it was before them, kept as a tuner candidate.
struct TiledGemmTiles {
  int bm = 64, bn = 64, bk = 16, tm = 4, tn = 4;
  bool pipelined = true;
  int invocations() const { return (bm / tm) * (bn / tn); }
  std::string text() const;  // "64x64x16 / 4x4" (", one step at a time" when not pipelined)
  // gemm_tiled.comp's PREFETCH and INTERLEAVE (constants 17, 18) and, for a convolution that is a
  // plain GEMM, POINTWISE (19): written only where one differs from the shader's default, so the
  // other kernels keep their constants (and their pipelines) as they were.
  void addConstants(std::vector<int32_t>& constants, bool pointwise = false) const;
  bool operator==(const TiledGemmTiles&) const = default;
};

// gemm_coopmat.comp: one subgroup MMA is M x N x K; a subgroup owns WM x WN of them and a
// workgroup SG_M x SG_N subgroups; k advances K * KSTEPS per shared-memory step.
struct CoopMatTiles {
  int m = 0, n = 0, k = 0;   // the device's size (CoopMatSize)
  int wm = 2, wn = 2;        // MMAs per subgroup along rows / columns
  int sgM = 2, sgN = 2;      // subgroups per workgroup along rows / columns
  int kSteps = 2;            // K blocks per shared-memory step
  bool pipelined = true;     // the next step's texels fetched while one multiplies (PREFETCH)
  int rows() const { return m * wm * sgM; }
  int cols() const { return n * wn * sgN; }
  // gemm_coopmat.comp's shared memory: the fp16 x and w slices of a step (rows padded by 8)
  // and the fp32 staging of one MMA result per subgroup.
  uint64_t sharedBytes() const {
    const uint64_t ld = uint64_t(k) * kSteps + 8;
    return (uint64_t(rows()) + cols()) * ld * 2 + uint64_t(sgM) * sgN * m * n * 4;
  }
  // Whether a workgroup of this shape fits the device (shared memory, invocations at its
  // largest subgroup size: full subgroups).
  bool fits(const DeviceCaps& caps) const;
  std::string text() const;
};

struct KernelPlan {
  KernelFamily gemm = KernelFamily::CpuBlocks;     // linear layers with fp32 weights
  KernelFamily gemmF16 = KernelFamily::CpuBlocks;  // linear layers with fp16 weights
  bool fp16Math = false;  // Tiled GEMM of fp16 weights computes in fp16 (gemm_tiled.comp, FP16_MATH)
  KernelFamily attention = KernelFamily::CpuBlocks;
  // attention of fp16 inputs or of layers with fp16 weights: CoopMat (attention_coopmat.comp)
  // where the device has cooperative matrices, else the attention family
  KernelFamily attentionF16 = KernelFamily::CpuBlocks;
  KernelFamily conv = KernelFamily::CpuBlocks;     // conv2d (Tiled: an implicit GEMM)
  bool cpuShapes = true;            // workgroup shapes of the other ops: a CPU's SIMD lanes or a GPU's
  bool subgroupReductions = false;  // norms and softmax combine partial results with subgroup ops
  // CPU family on a device whose subgroup's lanes share fetches (engine/ops/cpu_tiles.h), unless
  // the tiles are forced: the GEMM's columns (SHARED_COLUMNS), attention's keys (SHARED_KEYS) and
  // conv2d's weights (SHARED_WEIGHTS)
  bool gemmSharedColumns = false, attentionSharedKeys = false, convSharedWeights = false;
  // Inputs read through storage buffers instead of texel buffers (the *_sx kernels): where a
  // texel binding holds fewer floats than a storage binding (Vulkan's minimum is 65536 texels
  // against 128 MiB), so splitting by the storage range is all the ops need; SPAR_INPUTS forces
  // either way. fp16 inputs are read as pairs of halves in 32-bit words: no 16-bit storage needed.
  bool storageInputs = false;
  // The CPU family's GEMM of fp32 x and w as shaders/gemm_lanes.comp (a subgroup's lanes split
  // k, every load one vector load) instead of gemm.comp's register blocks: SwiftShader, whose
  // loads are per-lane gathers unless the lanes' addresses are consecutive. fp32 convolutions
  // then run as im2col and that GEMM (engine/ops/im2col.h: conv2d, conv_transpose2d).
  bool gemmLanesSplitK = false;
  // The CPU family's attention of fp32 q, k and v as shaders/attention_lanes.comp (a subgroup's
  // lanes split the head dimension, every load one word a lane at consecutive addresses)
  // instead of attention.comp's blocks of queries: SwiftShader, for the same reason.
  bool attentionLanesSplitDim = false;
  // The CPU family's GEMM (gemm_lanes.comp) and attention kernels with their specialization
  // constants written into the modules (engine/spirv_freeze.h), and attention in blocks small
  // enough to unroll: SwiftShader optimizes a shader only as far as its constants are plain
  // constants. (Its convolutions ran no faster so and took 3-8x longer to compile: not there.)
  bool freezeConstants = false;
  // The CPU family with gemm.comp's register blocks: transformer MLPs lay their hidden rows out
  // 4 elements wider where a row is a multiple of 2048 bytes, so that the 32 rows a block reads
  // at once fall in different sets of the CPU's L1 cache (engine/ops/row_padding.h).
  bool padAliasedRows = false;
  // The CPU family's gemm.comp (GROUP_M): workgroups go through every block of columns in groups
  // of this many blocks of rows, so that x's rows stay in cache while w streams (0: in the order
  // dispatched, each block of columns reading all of x again).
  int gemmRowGroups = 0;
  TiledGemmTiles gemmTiles;                          // products that fill the device
  // Products with few output tiles: twice the workgroups of 64 x 64 with 4 x 2 outputs an
  // invocation (a 2 x 2 block loads one value per multiply-add; the model's 768-wide products
  // landed there on the H200, docs/gpus.md).
  TiledGemmTiles gemmSmallTiles{64, 32, 16, 4, 2};
  CoopMatTiles coop;
  // GPU attention: queries a workgroup and keys a block; attentionLanes invocations share each 4
  // queries in attention_flash.comp (tiles of scores), 0 means attention_tiled.comp (one query an
  // invocation). Both are the tuner's candidates (engine/kernel_tuner.cpp).
  int attentionQueries = 32, attentionKeys = 32, attentionLanes = 16;
  bool measureTiles = false;  // GEMM tiles and attention blocks still to be measured (kernel_tuner.h)
  std::string source;        // "device properties", "SPAR_KERNELS=gpu", "measured ...", "cache ..."
  std::vector<std::string> reasons;  // one line per decision, for --list-kernels

  // The tiles for a product of M x N outputs: gemmTiles when they give enough workgroups to
  // fill the device, gemmSmallTiles otherwise.
  const TiledGemmTiles& tilesFor(int64_t m, int64_t n, int64_t batch) const;
  // The families that read block-quantized weights (DType::Q8 / Q4), dequantizing as they load
  // them: the cooperative-matrix kernel where fp16 weights take it (dequantized into its fp16
  // slices, as llama.cpp's Vulkan backend does; its activations are fp16 there too), else the
  // tiled one where the plan's f32 family for the op is tiled, else the register blocks (conv is
  // never CoopMat).
  KernelFamily quantizedGemm() const {
    if (gemmF16 == KernelFamily::CoopMat) return KernelFamily::CoopMat;
    return gemm == KernelFamily::Tiled ? KernelFamily::Tiled : KernelFamily::CpuBlocks;
  }
  KernelFamily quantizedConv() const { return conv; }
};

// From the device's properties and the overrides; throws Error for a forced family the device
// cannot run (coopmat without VK_KHR_cooperative_matrix, gpu-fp16 without shaderFloat16).
KernelPlan planKernels(const DeviceCaps& caps, const KernelTuning& tuning);

// The subgroup MMA size for fp16 A, B and fp32 C (16 x 16 x 16 preferred); m = 0 if none.
CoopMatSize coopMatF16Size(const DeviceCaps& caps);

// The GPU attention kernel and its blocks, in words ("attention_flash.comp (32 queries ...)").
std::string attentionText(const KernelPlan& plan);

// Human-readable lines: every op's family and tiles, and the reasons.
std::vector<std::string> describePlan(const KernelPlan& plan, const DeviceCaps& caps);

}  // namespace spar
