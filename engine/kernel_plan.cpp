#include "engine/kernel_plan.h"

#include <cstdio>

#include "spar/error.h"
#include "engine/ops/cpu_tiles.h"

namespace spar {

const char* familyName(KernelFamily family) {
  switch (family) {
    case KernelFamily::CpuBlocks: return "cpu register blocks";
    case KernelFamily::Tiled: return "gpu shared-memory tiles";
    case KernelFamily::CoopMat: return "gpu cooperative matrices";
  }
  return "?";
}

std::string TiledGemmTiles::text() const {
  char b[64];
  std::snprintf(b, sizeof(b), "%dx%dx%d / %dx%d%s", bm, bn, bk, tm, tn, pipelined ? "" : ", one step at a time");
  return b;
}

void TiledGemmTiles::addConstants(std::vector<int32_t>& constants, bool pointwise) const {
  constexpr size_t kPrefetchId = 17, kInterleaveId = 18, kPointwiseId = 19;
  if (pipelined && !pointwise) return;  // all at their defaults
  const size_t last = pointwise ? kPointwiseId : kInterleaveId;
  if (constants.size() <= last) constants.resize(last + 1, 0);  // ids before 17 default to 0 / false
  constants[kPrefetchId] = constants[kInterleaveId] = pipelined;
  if (pointwise) constants[kPointwiseId] = 1;
}

bool CoopMatTiles::fits(const DeviceCaps& caps) const {
  return sharedBytes() <= caps.maxSharedMemory &&
         uint64_t(caps.maxSubgroupSize) * sgM * sgN <= caps.maxWorkGroupInvocations;
}

std::string CoopMatTiles::text() const {
  char b[96];
  std::snprintf(b, sizeof(b), "%dx%dx%d MMA, %dx%d per subgroup, %dx%d subgroups, k step %d%s", m, n, k, wm, wn,
                sgM, sgN, k * kSteps, pipelined ? "" : ", one step at a time");
  return b;
}

std::string attentionText(const KernelPlan& plan) {
  const std::string blocks = std::to_string(plan.attentionQueries) + " queries a workgroup, " +
                             std::to_string(plan.attentionKeys) + "-key blocks";
  if (plan.attentionLanes == 0) return "attention_tiled.comp (" + blocks + ", one query an invocation)";
  return "attention_flash.comp (" + blocks + ", " + std::to_string(plan.attentionLanes) +
         " invocations sharing each 4 queries' scores and outputs)";
}

const TiledGemmTiles& KernelPlan::tilesFor(int64_t m, int64_t n, int64_t batch) const {
  // A GPU needs a few workgroups per compute unit to hide memory latency; 256 workgroups fill
  // the largest GPUs (an H200 has 132 multiprocessors), and below that smaller tiles win.
  const int64_t groups = (m + gemmTiles.bm - 1) / gemmTiles.bm * ((n + gemmTiles.bn - 1) / gemmTiles.bn) * batch;
  return groups >= 256 ? gemmTiles : gemmSmallTiles;
}

CoopMatSize coopMatF16Size(const DeviceCaps& caps) {
  constexpr int kF16 = 0, kF32 = 1;
  CoopMatSize best;
  for (const auto& s : caps.coopMatSizes) {
    if (s.aType != kF16 || s.bType != kF16 || s.cType != kF32 || s.resultType != kF32) continue;
    if (s.m % 8 || s.n % 8 || s.k % 8 || s.m > 32 || s.n > 32 || s.k > 32) continue;
    const bool preferred = s.m == 16 && s.n == 16 && s.k == 16;
    if (best.m == 0 || preferred) best = s;
    if (preferred) break;
  }
  return best;
}

KernelPlan planKernels(const DeviceCaps& caps, const KernelTuning& tuning) {
  KernelPlan plan;
  const std::string& forced = tuning.kernels;
  const bool gpu = forced.empty() ? !caps.isCpu() : forced != "cpu";
  plan.source = forced.empty() ? "device properties" : "SPAR_KERNELS=" + forced;
  const bool shortTexels = caps.maxTexelBufferElements * 4 < caps.maxStorageBufferRange;
  plan.storageInputs = tuning.inputs.empty() ? shortTexels : tuning.inputs == "storage";
  if (!tuning.inputs.empty())
    plan.reasons.push_back("inputs through " + std::string(plan.storageInputs ? "storage buffers (*_sx kernels)" : "texel buffers") +
                           ": forced (SPAR_INPUTS=" + tuning.inputs + ")");
  else if (plan.storageInputs)
    plan.reasons.push_back("inputs through storage buffers of 32-bit words, fp32 or fp16 (*_sx kernels): a texel buffer "
                           "holds " + std::to_string(caps.maxTexelBufferElements) + " texels, less than a storage binding's " +
                           std::to_string(caps.maxStorageBufferRange >> 20) + " MiB");
  if (!gpu) {
    plan.reasons.push_back(forced.empty()
                               ? "CPU device: register blocks through texel buffers, no shared memory (on llvmpipe shared "
                                 "memory is a loop over the SIMD lanes and a coroutine switch per barrier)"
                               : "forced: the CPU family");
    const bool share = ops::cpuLanesShareFetches(caps);
    plan.gemmSharedColumns = share && !tuning.gemmTiles;
    plan.attentionSharedKeys = share && !tuning.attentionTiles;
    // conv2d's weights: measured faster on Mesa 22.3 at 8 and 16 lanes (conv3x3 64 -> 64 at
    // 128x128: 22.3 -> 18.8 ms and 16.4 -> 13.4 ms; CV-DRP's 1x1 head 4.3 -> 2.6 and 8.4 -> 3.7
    // ms), not on Mesa 25.0.7 (the same 31.5 ms; the head 2.2 -> 3.8 ms), which keeps its blocks.
    plan.convSharedWeights = share && !tuning.convTiles && ops::cpuTiles(caps) != ops::CpuTiles::Newer;
    // SwiftShader (docs/portability.md, "SwiftShader's kernels"): 1024^3 GEMM 0.6-0.8 -> 4.7
    // GFLOPS, attention 1.0 -> 1.6 (constants written in) -> 2.2 (attention_lanes.comp).
    const bool swiftShader = caps.driverId == VK_DRIVER_ID_GOOGLE_SWIFTSHADER;
    // A kernel whose subgroup's lanes split a reduction (gemm_lanes.comp, attention_lanes.comp):
    // SwiftShader's plan unless forced (ENV=1 / 0, KernelTuning); it needs subgroup arithmetic
    // with full subgroups, and a device without them refuses it when forced.
    auto lanesSplit = [&](const std::optional<bool>& forced, bool byDefault, const std::string& env,
                          const std::string& what, const std::string& why) {
      bool on = forced.value_or(byDefault);
      if (on && !(caps.subgroupArithmetic && caps.fullSubgroups)) {
        if (forced) throw Error(env + "=1: the device has no subgroup arithmetic with full subgroups");
        on = false;
      }
      if (forced) plan.reasons.push_back(what + ": " + (on ? "forced" : "forced off") + " (" + env + ")");
      else if (on) plan.reasons.push_back("SwiftShader: " + what + ", " + why);
      return on;
    };
    plan.gemmLanesSplitK = lanesSplit(tuning.gemmLanesSplitK, swiftShader && !tuning.gemmTiles, "SPAR_GEMM_LANES",
                                      "GEMMs of fp32 weights with the subgroup's lanes splitting k (gemm_lanes.comp), "
                                      "and convolutions (transposed ones too) as im2col and that GEMM",
                                      "its loads are vector loads only where the lanes' addresses are consecutive");
    plan.attentionLanesSplitDim =
        lanesSplit(tuning.attentionLanesSplitDim, swiftShader && !tuning.attentionTiles, "SPAR_ATTENTION_LANES",
                   "attention of fp32 q, k and v with the subgroup's lanes splitting the head dimension "
                   "(attention_lanes.comp)",
                   "for the same reason");
    // The official model on llvmpipe 22.3 (spar-bench --model, 4 + 4 views at 256x256, runs in the
    // order A B C C B A): 25.1 s as dispatched, 24.3 s with the hidden rows widened, 22.3 s with
    // them widened and 8 blocks of rows a group; one GEMM alone (2056 x 3072 x 768, its inputs
    // in cache) 79-83 -> 108-118 GFLOPS from the widening. SwiftShader's gemm_lanes.comp ran the
    // same either way (it is bound by its arithmetic), so its plan widens nothing.
    plan.padAliasedRows = tuning.padAliasedRows.value_or(!plan.gemmLanesSplitK);
    if (tuning.padAliasedRows)
      plan.reasons.push_back(std::string("transformer MLPs' hidden rows: ") +
                             (plan.padAliasedRows ? "widened" : "as the model has them") + ": forced (SPAR_ROW_PADDING)");
    else if (plan.padAliasedRows)
      plan.reasons.push_back("transformer MLPs' hidden rows 4 elements wider where a row is a multiple of 2048 bytes: rows "
                             "4096 bytes apart share one set of a CPU's L1 cache, and a GEMM block reads 32 of them at once");
    plan.gemmRowGroups = tuning.gemmRowGroups.value_or(8);
    if (plan.gemmRowGroups == 0)
      plan.reasons.push_back("gemm.comp's workgroups in the order dispatched: forced (SPAR_GEMM_ROW_GROUPS=0)");
    else
      plan.reasons.push_back("gemm.comp's workgroups through the columns in groups of " + std::to_string(plan.gemmRowGroups) +
                             " blocks of rows" + (tuning.gemmRowGroups ? " (forced: SPAR_GEMM_ROW_GROUPS)" : "") +
                             ": a CPU runs workgroups in index order, and x's rows stay in its caches only while a "
                             "group reuses them");
    plan.freezeConstants = tuning.freezeConstants.value_or(swiftShader);
    if (tuning.freezeConstants)
      plan.reasons.push_back(std::string("GEMM and attention kernels: specialization constants ") +
                             (plan.freezeConstants ? "written into the modules" : "specialized") + ": forced (SPAR_FREEZE_CONSTANTS)");
    else if (plan.freezeConstants)
      plan.reasons.push_back("GEMM and attention kernels: specialization constants written into the modules, attention in "
                             "blocks of 2 queries x 4 keys: SwiftShader specializes by changing the constants' defaults, and "
                             "its optimizer then unrolls no loop and keeps no array in registers that they bound");
    if (share)
      plan.reasons.push_back("llvmpipe with subgroup shuffles and full subgroups: a workgroup is one subgroup whose lanes "
                             "share the texels all of them read (a texel fetch there is a call that spills the registers)" +
                             std::string(tuning.gemmTiles || tuning.attentionTiles || tuning.convTiles
                                             ? "; not where tiles are forced"
                                             : ""));
    return plan;
  }
  plan.gemm = plan.gemmF16 = plan.attention = plan.attentionF16 = plan.conv = KernelFamily::Tiled;
  plan.cpuShapes = false;
  plan.reasons.push_back(forced.empty() ? std::string(caps.isCpu() ? "CPU" : "GPU") +
                                              " device: workgroup tiles in shared memory (" +
                                              std::to_string(caps.maxSharedMemory / 1024) + " KiB a workgroup)"
                                        : "forced: the GPU family on a " + std::string(caps.isCpu() ? "CPU" : "GPU") +
                                              " device");
  plan.subgroupReductions = caps.subgroupArithmetic && caps.subgroupSize >= 4;
  plan.reasons.push_back(plan.subgroupReductions
                             ? "norms and softmax reduce with subgroup operations (subgroup size " +
                                   std::to_string(caps.subgroupSize) + ")"
                             : "no subgroup arithmetic in compute shaders: reductions through shared memory");
  // GEMM tiles: 64 x 64 outputs a workgroup of 256 invocations, 4 x 4 each, from 16 k a step
  // (8 KiB of shared memory); 128 x 128 / 8 x 8 is the other common GPU choice, measured
  // among the candidates (kernel_tuner.cpp). Small products get 64 x 32 so that they still
  // spread over the device.
  plan.gemmTiles = {64, 64, 16, 4, 4};
  if (tuning.gpuGemmTiles) {
    const auto& t = *tuning.gpuGemmTiles;
    plan.gemmTiles = plan.gemmSmallTiles = {t[0], t[1], t[2], t[3], t[4], t[5] != 0};
    plan.reasons.push_back("GEMM tiles forced: " + plan.gemmTiles.text());
  } else {
    // Any tile forced by the user means no measuring: the plan is what they asked for.
    plan.measureTiles = !tuning.gpuAttentionTiles && !tuning.coopMatTiles && tuning.measureKernels.value_or(!caps.isCpu());
    plan.reasons.push_back("GEMM tiles " + plan.gemmTiles.text() + " (" + plan.gemmSmallTiles.text() +
                           " below 256 workgroups)" +
                           (plan.measureTiles ? ", to be measured against other candidates at first use" : ""));
  }
  if (plan.gemmTiles.invocations() > int(caps.maxWorkGroupInvocations)) {
    if (tuning.gpuGemmTiles)
      throw Error("GPU GEMM tiles " + plan.gemmTiles.text() + " need more invocations than the device allows");
    // Fewer invocations (128 is all Vulkan guarantees): halve the tile's columns, then rows.
    for (TiledGemmTiles* t : {&plan.gemmTiles, &plan.gemmSmallTiles})
      while (t->invocations() > int(caps.maxWorkGroupInvocations) && t->bn > t->tn) (t->bn >= t->bm ? t->bn : t->bm) /= 2;
    plan.reasons.push_back("GEMM tiles within " + std::to_string(caps.maxWorkGroupInvocations) + " invocations: " +
                           plan.gemmTiles.text() + " (" + plan.gemmSmallTiles.text() + ")");
  }
  if (tuning.gpuAttentionTiles) {
    plan.attentionQueries = (*tuning.gpuAttentionTiles)[0];
    plan.attentionKeys = (*tuning.gpuAttentionTiles)[1];
    plan.attentionLanes = (*tuning.gpuAttentionTiles)[2];
  }
  // Several invocations a query (attention_flash.comp) by default: one query an invocation
  // (attention_tiled.comp) left an H200 7/8 idle at the model's 2816 tokens x 12 heads
  // (docs/gpus.md); the tuner times both kernels wherever it measures.
  plan.reasons.push_back("attention: " + attentionText(plan) + ", online softmax" +
                         (plan.measureTiles ? ", to be measured against other blocks and attention_tiled.comp at first use" : ""));
  plan.reasons.push_back("conv2d: implicit GEMM on the GEMM tiles (im2col while loading a tile)");

  // fp16 weights (the fp16 precision): cooperative matrices where the device multiplies fp16
  // into fp32, else fp16 arithmetic where it has it, else the fp32 tiles (texel fetches convert
  // the weights). SPAR_KERNELS=gpu keeps the fp32 tiles, gpu-fp16 / coopmat force the others.
  const CoopMatSize cm = coopMatF16Size(caps);
  if (forced == "coopmat" && cm.m == 0)
    throw Error("SPAR_KERNELS=coopmat: " + caps.name + " reports no VK_KHR_cooperative_matrix size with fp16 A, B and fp32 C");
  if (forced == "gpu-fp16" && !caps.shaderFloat16)
    throw Error("SPAR_KERNELS=gpu-fp16: " + caps.name + " has no fp16 arithmetic (shaderFloat16)");
  if ((forced.empty() || forced == "coopmat") && cm.m != 0) {
    plan.gemmF16 = KernelFamily::CoopMat;
    plan.coop.m = int(cm.m);
    plan.coop.n = int(cm.n);
    plan.coop.k = int(cm.k);
    if (const auto& t = tuning.coopMatTiles) {
      plan.coop.wm = (*t)[0], plan.coop.wn = (*t)[1], plan.coop.sgM = (*t)[2], plan.coop.sgN = (*t)[3];
      plan.coop.kSteps = (*t)[4];
      plan.coop.pipelined = (*t)[5] != 0;
      if (!plan.coop.fits(caps))
        throw Error("SPAR_COOPMAT_TILES " + plan.coop.text() + ": needs " + std::to_string(plan.coop.sharedBytes()) +
                    " bytes of shared memory and " + std::to_string(caps.maxSubgroupSize * plan.coop.sgM * plan.coop.sgN) +
                    " invocations; " + caps.name + " has " + std::to_string(caps.maxSharedMemory) + " and " +
                    std::to_string(caps.maxWorkGroupInvocations));
    }
    plan.attentionF16 = KernelFamily::CoopMat;
    plan.reasons.push_back("fp16 weights: VK_KHR_cooperative_matrix " + plan.coop.text() + ", fp32 accumulation" +
                           (plan.measureTiles ? ", the workgroup shape to be measured at first use" : ""));
    plan.reasons.push_back("attention of fp16 layers: q k^T and p v on cooperative matrices, softmax in fp32");
  } else if (forced == "gpu-fp16" || (forced.empty() && caps.shaderFloat16)) {
    plan.fp16Math = true;
    plan.reasons.push_back("fp16 weights: fp16 arithmetic (shaderFloat16) in runs of 4 k, fp32 accumulation" +
                           std::string(forced.empty() ? " (no cooperative-matrix size with fp16 A, B and fp32 C)" : ""));
  } else {
    plan.reasons.push_back(std::string("fp16 weights: the fp32 tiles (") +
                           (forced.empty() ? "no cooperative matrices, no fp16 arithmetic" : "forced") + ")");
  }
  return plan;
}

std::vector<std::string> describePlan(const KernelPlan& plan, const DeviceCaps& caps) {
  std::vector<std::string> out;
  char line[256];
  std::snprintf(line, sizeof(line), "device: %s (%s), vendor 0x%04x, subgroup size %u, shared memory %u KiB, fp16 arithmetic %s",
                caps.name.c_str(), caps.isCpu() ? "CPU" : "GPU", caps.vendorId, caps.subgroupSize,
                caps.maxSharedMemory / 1024, caps.shaderFloat16 ? "yes" : "no");
  out.push_back(line);
  std::string sizes;
  for (const auto& s : caps.coopMatSizes) {
    static const char* names[] = {"f16", "f32", "f64", "s8", "s16", "s32", "s64", "u8", "u16", "u32", "u64"};
    auto name = [&](int t) { return t >= 0 && t < 11 ? names[t] : "?"; };
    std::snprintf(line, sizeof(line), "%s%ux%ux%u %s*%s+%s", sizes.empty() ? "" : ", ", s.m, s.n, s.k, name(s.aType),
                  name(s.bType), name(s.cType));
    sizes += line;
  }
  out.push_back("cooperative matrices: " + (caps.cooperativeMatrix ? sizes : std::string("none")));
  out.push_back(std::string("chosen from: ") + plan.source);
  out.push_back(std::string("inputs: ") + (plan.storageInputs ? "storage buffers of 32-bit words, fp32 or fp16 (*_sx kernels)"
                                                               : "texel buffers"));
  auto gemmText = [&](KernelFamily f, bool f16) {
    if (f == KernelFamily::CpuBlocks) {
      // engine/ops/linear.cpp, chooseGemmTiles
      const bool shared = plan.gemmSharedColumns, newer = ops::cpuTiles(caps) == ops::CpuTiles::Newer;
      return std::string("gemm.comp (") + familyName(f) +
             (!shared ? ""
              : newer ? "; from 2^28 multiply-adds 4 x 32 columns shared by the subgroup's lanes"
                      : "; 4 x 16 columns shared by the subgroup's lanes, 4 x 32 from 2^28 multiply-adds") + ")";
    }
    if (f == KernelFamily::CoopMat) return "gemm_coopmat.comp (" + plan.coop.text() + ")";
    return "gemm_tiled.comp (" + plan.gemmTiles.text() + ", small " + plan.gemmSmallTiles.text() +
           (f16 && plan.fp16Math ? ", fp16 arithmetic" : "") + ")";
  };
  out.push_back("linear, fp32 weights: " +
                (plan.gemm == KernelFamily::CpuBlocks && plan.gemmLanesSplitK
                     ? std::string("gemm_lanes.comp (4 x 8 a subgroup, its lanes splitting k") +
                           (plan.freezeConstants ? "; constants written into the module)" : ")")
                     : gemmText(plan.gemm, false)));
  out.push_back("linear, fp16 weights: " + gemmText(plan.gemmF16, true));
  out.push_back("linear, q8 / q4 weights: " + gemmText(plan.quantizedGemm(), false) + ", dequantizing");
  if (plan.attention == KernelFamily::CpuBlocks && plan.attentionLanesSplitDim)
    out.push_back(std::string("attention, fp32 q, k, v: attention_lanes.comp (2 queries x 4 keys a subgroup, its lanes "
                              "splitting the head dimension") +
                  (plan.freezeConstants ? "; constants written into the module)" : ")"));
  out.push_back(plan.attention == KernelFamily::CpuBlocks
                    ? std::string("attention: attention.comp (cpu register blocks") +
                          (plan.attentionSharedKeys ? "; each block's keys shared by the subgroup's lanes)"
                           : plan.freezeConstants   ? "; 2 queries x 4 keys, constants written into the module)"
                                                    : ")")
                    : "attention: " + attentionText(plan));
  if (plan.attentionF16 == KernelFamily::CoopMat)
    out.push_back("attention, fp16 layers: attention_coopmat.comp (" + std::to_string(plan.coop.m) + "x" +
                  std::to_string(plan.coop.n) + "x" + std::to_string(plan.coop.k) + " MMA)");
  out.push_back(plan.conv == KernelFamily::CpuBlocks && plan.gemmLanesSplitK
                    ? std::string("conv2d, conv_transpose2d: im2col.comp and gemm_lanes.comp (fp32 kernels; quantized "
                                  "ones conv2d.comp)")
                : plan.conv == KernelFamily::CpuBlocks
                    ? std::string("conv2d: conv2d.comp (cpu register blocks") +
                          (plan.convSharedWeights ? "; each step's weights shared by the subgroup's lanes)" : ")")
                    : "conv2d: gemm_tiled.comp, CONV (implicit GEMM)");
  out.push_back(std::string("reductions: ") + (plan.subgroupReductions ? "subgroup operations" : "shared memory") +
                ", workgroup shapes for " + (plan.cpuShapes ? "CPU SIMD lanes" : "GPUs"));
  for (const auto& r : plan.reasons) out.push_back("why: " + r);
  return out;
}

}  // namespace spar
