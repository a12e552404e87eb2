#include "engine/ops/attention.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include "engine/engine.h"
#include "spar/error.h"
#include "engine/ops/cpu_tiles.h"
#include "engine/ops/norm.h"
#include "engine/ops/rope.h"

namespace spar {
namespace {

struct AttentionPush {
  int32_t Nq, Nk;
  int32_t qStride, kStride, vStride, oStride;
  int32_t qOff, kOff, vOff, oOff;
  int32_t qBatch, kBatch, vBatch, oBatch;
  float scaleLog2;
  float qkEps = 0;         // attention_prep.glsl (attention.comp, attention_tiled.comp only)
  int32_t ropePrefix = 0;
};

// attention_prep.glsl's QK_NORM and QK_ROPE (specialization constants 12 and 13).
constexpr size_t kQkNormId = 12, kQkRopeId = 13;
void withPrep(std::vector<int32_t>& constants, const QkPrep& prep) {
  if (!prep.any()) return;
  if (constants.size() <= kQkRopeId) constants.resize(kQkRopeId + 1, 0);
  constants[kQkNormId] = prep.normWeight.defined();
  constants[kQkRopeId] = prep.ropeSin.defined();
}

// The bindings of a kernel with attention_prep.glsl: q, k, v, out, then the norm weight and the
// RoPE tables (q where unused: never read).
std::vector<Bind> prepBinds() {
  return {Bind::Texel, Bind::Texel, Bind::Texel, Bind::Write, Bind::Texel, Bind::Texel, Bind::Texel};
}
std::vector<Arg> prepArgs(const std::vector<Arg>& args, const QkPrep& prep, const Tensor& q) {
  std::vector<Arg> all = args;
  all.push_back(Arg::texel(prep.normWeight.defined() ? prep.normWeight : q, 4));
  all.push_back(Arg::texel(prep.ropeSin.defined() ? prep.ropeSin : q, 4));
  all.push_back(Arg::texel(prep.ropeCos.defined() ? prep.ropeCos : q, 4));
  return all;
}

// The prep's tensors against the fused qkv layout it needs; throws where they do not fit.
void checkPrep(const QkPrep& prep, const HeadsView& q, const HeadsView& k, int heads, int headDim) {
  const Tensor& t = q.tensor;
  const bool fused = t.bufferPtr() == k.tensor.bufferPtr() && t.byteOffset() == k.tensor.byteOffset() &&
                     t.shape() == k.tensor.shape() && t.rank() == 3 && q.column == 0 &&
                     k.column == int64_t(heads) * headDim && t.dtype() == DType::F32;
  if (!fused) throw Error("attention: q / k preparation needs q and k in one f32 [B, N, C] qkv tensor (q at 0, k at D)");
  if (prep.normWeight.defined() &&
      (prep.normWeight.shape() != Shape{2, headDim} || prep.normWeight.dtype() != DType::F32))
    throw Error("attention: the q / k norm weight must be f32 [2, " + std::to_string(headDim) + "], got " +
                prep.normWeight.describe());
  if (prep.ropeSin.defined() != prep.ropeCos.defined()) throw Error("attention: RoPE needs both tables");
  if (prep.ropeSin.defined()) {
    const Shape want{t.dim(1) - prep.ropePrefix, headDim};
    if (prep.ropePrefix < 0 || headDim % 2 || prep.ropeSin.shape() != want || prep.ropeCos.shape() != want ||
        prep.ropeSin.dtype() != DType::F32 || prep.ropeCos.dtype() != DType::F32)
      throw Error("attention: RoPE tables must be f32 " + shapeString(want) + ", got " + prep.ropeSin.describe());
  }
}

struct Geometry {
  int64_t batch, rows, cols;
};

Geometry geometryOf(const HeadsView& h, const char* what, int heads, int headDim) {
  const Tensor& t = h.tensor;
  if (t.rank() != 2 && t.rank() != 3) throw Error(std::string("attention: ") + what + " must be [B, N, C] or [N, C]");
  Geometry g{t.rank() == 3 ? t.dim(0) : 1, t.dim(-2), t.dim(-1)};
  if (h.column < 0 || h.column + int64_t(heads) * headDim > g.cols)
    throw Error(std::string("attention: ") + what + " " + t.describe() + " has no room for " + std::to_string(heads) +
                " heads of " + std::to_string(headDim) + " at column " + std::to_string(h.column));
  return g;
}

// shaders/attention_coopmat.comp for this head size, or null where the head size is not a
// multiple of the multiply-add's or its shared memory does not fit: 4 subgroups of the
// multiply-add's rows, blocks of twice its columns of keys, fewer subgroups where needed.
const Kernel* coopMatKernel(Engine& engine, const KernelPlan& plan, int headDim, bool causal, bool f16Out,
                            const QkPrep& prep) {
  const DeviceCaps& caps = engine.caps();
  const CoopMatTiles& c = plan.coop;
  if (headDim % c.k || headDim % c.n) return nullptr;
  const uint64_t dh = uint64_t(headDim), keys = 2 * uint64_t(std::max(c.n, c.k));
  for (uint64_t groups = 4; groups >= 1; groups /= 2) {
    const uint64_t rows = groups * uint64_t(c.m), ld = dh + 8;
    const uint64_t shared = std::max(rows, keys) * ld * 2 + keys * ld * 2 + rows * keys * 4 + rows * (keys + 8) * 2 +
                            rows * dh * 4 + 2 * rows * 4;
    if (shared > caps.maxSharedMemory) continue;
    std::vector<int32_t> constants = {int(caps.maxSubgroupSize * groups), 1, 1, headDim, int(groups), int(keys), causal};
    constants.resize(20, 0);  // ids 7-19 unused but QK_NORM, QK_ROPE (12, 13); 20-22 the multiply-add shape
    withPrep(constants, prep);
    constants.insert(constants.end(), {c.m, c.n, c.k});
    return &engine.kernel({std::string("attention_coopmat") + (prep.any() ? "_prep" : "") + (f16Out ? "_f16out" : "_f32"),
                           prep.any() ? prepBinds() : std::vector<Bind>{Bind::Texel, Bind::Texel, Bind::Texel, Bind::Write},
                           sizeof(AttentionPush),
                           constants,
                           caps.maxSubgroupSize});
  }
  return nullptr;
}

// shaders/attention_flash.comp (KernelPlan::attentionLanes > 0): the plan's queries a
// workgroup, lanes a group of 4 queries and keys a block (a multiple of the lanes). Where the
// shared memory (q, k and v rows, the probabilities, the row partials) does not hold that, the
// key block shrinks, then the lanes halve (down to 4), so a device with little shared memory
// (16 KiB on a Raspberry Pi 5) still gets the kernel. Null where nothing fits. Subgroup shuffles
// combine a group's rows (SG_ROWS) where the device's subgroups hold whole groups and the
// pipeline can require full subgroups.
struct FlashChoice {
  const Kernel* kernel = nullptr;
  int queries = 0;
};
FlashChoice flashKernel(Engine& engine, const KernelPlan& plan, int headDim, bool causal, bool f16Out,
                        const QkPrep& prep) {
  const DeviceCaps& caps = engine.caps();
  const int queries = plan.attentionQueries;
  if (plan.attentionLanes <= 0 || queries % 4) return {};
  const uint32_t fixedSize = caps.requiredSubgroupSize && caps.minSubgroupSize != caps.maxSubgroupSize
                                 ? caps.maxSubgroupSize
                                 : (caps.minSubgroupSize ? caps.minSubgroupSize : caps.subgroupSize);
  for (int lanes = plan.attentionLanes; lanes >= 1; lanes = lanes >= 8 ? lanes / 2 : 0) {
    const int invocations = queries / 4 * lanes;
    if (invocations > int(caps.maxWorkGroupInvocations)) continue;
    const bool sg = caps.subgroupShuffle && caps.fullSubgroups && (lanes & (lanes - 1)) == 0 &&
                    uint32_t(lanes) <= fixedSize && caps.maxSubgroupSize &&
                    invocations % int(caps.maxSubgroupSize) == 0;
    auto sharedBytes = [&](int keys) { return attentionFlashSharedBytes(queries, keys, sg ? 0 : lanes, headDim); };
    int keys = std::max(lanes, plan.attentionKeys / lanes * lanes);
    while (keys > lanes && sharedBytes(keys) > caps.maxSharedMemory) keys -= lanes;
    if (sharedBytes(keys) > caps.maxSharedMemory) continue;
    std::vector<int32_t> constants = {invocations, 1, 1, headDim, keys, causal ? 1 : 0, queries, lanes};
    withPrep(constants, prep);
    const Kernel& kernel =
        engine.kernel({std::string("attention_flash") + (sg ? "_sg" : "") + (prep.any() ? "_prep" : "") +
                           (f16Out ? "_f16out" : "_f32"),
                       prep.any() ? prepBinds() : std::vector<Bind>{Bind::Texel, Bind::Texel, Bind::Texel, Bind::Write},
                       sizeof(AttentionPush), constants, sg ? caps.maxSubgroupSize : 0u});
    return {&kernel, queries};
  }
  return {};
}

// The q / k preparation as its own ops, in place in the fused qkv tensor (the kernels without
// attention_prep.glsl).
void prepareInPlace(Recorder& rec, const Tensor& qkv, int heads, int headDim, const QkPrep& prep) {
  if (prep.normWeight.defined()) {
    const Tensor rows = qkv.reshape({qkv.dim(0) * qkv.dim(1), qkv.dim(2)});
    rmsNormHeads(rec, rows, 0, rows, 0, 2 * int64_t(heads), prep.normWeight, prep.normEps);
  }
  if (prep.ropeSin.defined()) rope(rec, qkv, heads, headDim, prep.ropePrefix, prep.ropeSin, prep.ropeCos);
}

}  // namespace

uint64_t attentionFlashSharedBytes(int queries, int keys, int partialLanes, int headDim) {
  const uint64_t row = uint64_t(headDim / 4 + 1) * 16;  // a q, k or v row and its pad texel
  return (uint64_t(queries) + 2 * uint64_t(keys)) * row + 4 * uint64_t(queries) * (keys + 1) +
         4 * uint64_t(queries) * partialLanes;
}

bool preparesInKernel(Engine& engine, int headDim, const QkPrep& prep, bool coopMat) {
  const KernelPlan& plan = engine.plan();
  const DeviceCaps& caps = engine.caps();
  const bool splitDim = plan.attention == KernelFamily::CpuBlocks && plan.attentionLanesSplitDim &&
                        headDim % int(caps.subgroupSize) == 0;
  // attention_prep.glsl's 7 bindings are storage buffers where the plan reads inputs so (a
  // device may allow 4 a kernel). RoPE pairs channel c with c + headDim / 2: in texels u and
  // u + headDim / 8 (attention.comp, attention_tiled.comp), or in the same lane of
  // attention_lanes.comp where each lane owns an even number of channels.
  const bool fits = plan.storageInputs ? caps.maxPerStageStorageBuffers >= 7 : caps.maxPerStageSampledImages >= 6;
  const bool ropePairs = splitDim && !coopMat ? (headDim / int(caps.subgroupSize)) % 2 == 0 : headDim % 8 == 0;
  return fits && (!prep.ropeSin.defined() || ropePairs);
}

void attention(Recorder& rec, const HeadsView& q, const HeadsView& k, const HeadsView& v, const HeadsView& out,
               int heads, int headDim, bool causal, float scale, bool fp16Layer, const QkPrep& prep) {
  Engine& engine = rec.engine();
  if (heads <= 0 || headDim <= 0 || headDim % 4 != 0)
    throw Error("attention: head dimension must be a positive multiple of 4, got " + std::to_string(headDim));
  const Geometry gq = geometryOf(q, "q", heads, headDim), gk = geometryOf(k, "k", heads, headDim),
                 gv = geometryOf(v, "v", heads, headDim), go = geometryOf(out, "out", heads, headDim);
  if (gk.rows != gv.rows || gq.rows != go.rows || gq.batch != gk.batch || gq.batch != gv.batch || gq.batch != go.batch)
    throw Error("attention: q, k, v and out shapes do not agree");
  if (causal && gq.rows != gk.rows) throw Error("attention: a causal mask needs as many queries as keys");
  for (const auto* g : {&gq, &gk, &gv})
    if (g->cols % 4) throw Error("attention: q, k, v row lengths must be multiples of 4");
  if (q.column % 4 || k.column % 4 || v.column % 4) throw Error("attention: head columns must be multiples of 4");
  if (out.tensor.dtype() == DType::I32) throw Error("attention: integer output");
  if (prep.any()) checkPrep(prep, q, k, heads, headDim);
  if (gq.rows == 0 || gk.rows == 0) return;
  if (out.tensor.bytes() > engine.device().bindingRangeLimit())
    throw Error("attention: output " + out.tensor.describe() + " exceeds the device's storage binding range");

  const float s = scale != 0.0f ? scale : 1.0f / std::sqrt(static_cast<float>(headDim));
  AttentionPush push{int32_t(gq.rows), int32_t(gk.rows),
                     int32_t(gq.cols), int32_t(gk.cols), int32_t(gv.cols), int32_t(go.cols),
                     int32_t(q.column), int32_t(k.column), int32_t(v.column), int32_t(out.column),
                     int32_t(gq.rows * gq.cols), int32_t(gk.rows * gk.cols), int32_t(gv.rows * gv.cols),
                     int32_t(go.rows * go.cols), s * 1.4426950408889634f, prep.normEps,
                     int32_t(prep.ropePrefix)};
  const std::vector<Arg> args = {Arg::texel(q.tensor, 4), Arg::texel(k.tensor, 4), Arg::texel(v.tensor, 4),
                                 Arg::out(out.tensor)};
  const bool f16Out = out.tensor.dtype() == DType::F16;

  const KernelPlan& plan = engine.plan();
  const bool halfInputs = q.tensor.dtype() == DType::F16 && k.tensor.dtype() == DType::F16 &&
                          v.tensor.dtype() == DType::F16;
  const int lanes = int(engine.caps().subgroupSize);
  const bool fp32Inputs = q.tensor.dtype() == DType::F32 && k.tensor.dtype() == DType::F32 &&
                          v.tensor.dtype() == DType::F32;
  const bool coopMat = plan.attentionF16 == KernelFamily::CoopMat && (fp16Layer || halfInputs) &&
                       coopMatKernel(engine, plan, headDim, causal, f16Out, {}) != nullptr;
  const bool splitDim = plan.attention == KernelFamily::CpuBlocks && plan.attentionLanesSplitDim && fp32Inputs &&
                        headDim % lanes == 0;
  if (prep.any() && !preparesInKernel(engine, headDim, prep, coopMat)) {
    prepareInPlace(rec, q.tensor, heads, headDim, prep);
    attention(rec, q, k, v, out, heads, headDim, causal, scale, fp16Layer);
    return;
  }
  // The *_prep variants of attention.comp and attention_tiled.comp have the prep's bindings.
  const std::vector<Bind> binds =
      prep.any() ? prepBinds() : std::vector<Bind>{Bind::Texel, Bind::Texel, Bind::Texel, Bind::Write};
  const std::vector<Arg> boundArgs = prep.any() ? prepArgs(args, prep, q.tensor) : args;
  const std::string prepSuffix = prep.any() ? "_prep" : "";
  if (coopMat) {
    if (const Kernel* kernel = coopMatKernel(engine, plan, headDim, causal, f16Out, prep)) {
      const uint32_t queries = uint32_t(kernel->spec.constants[4]) * uint32_t(plan.coop.m);
      rec.dispatch(*kernel, boundArgs, push, static_cast<uint32_t>((gq.rows + queries - 1) / queries),
                   static_cast<uint32_t>(heads), static_cast<uint32_t>(gq.batch));
      return;
    }
  }
  if (plan.attention == KernelFamily::Tiled) {
    const FlashChoice flash = flashKernel(engine, plan, headDim, causal, f16Out, prep);
    if (flash.kernel) {
      rec.dispatch(*flash.kernel, boundArgs, push, static_cast<uint32_t>((gq.rows + flash.queries - 1) / flash.queries),
                   static_cast<uint32_t>(heads), static_cast<uint32_t>(gq.batch));
      return;
    }
    // GPU family (shaders/attention_tiled.comp): a workgroup per block of queries of a head;
    // keys per block bounded by the shared memory their k and v rows take.
    const int queries = std::min<int>(plan.attentionQueries, int(engine.caps().maxWorkGroupInvocations));
    int keys = plan.attentionKeys;
    // (a multiple of 4: the shader's chunks of 4 or 8 keys divide the block)
    while (keys > 4 && uint64_t(keys) * headDim * 8 > engine.caps().maxSharedMemory) keys = std::max(4, keys / 8 * 4);
    std::vector<int32_t> constants = {queries, 1, 1, headDim, keys, causal ? 1 : 0};
    withPrep(constants, prep);
    const Kernel& kernel = engine.kernel({"attention_tiled" + prepSuffix + (f16Out ? "_f16out" : "_f32"), binds,
                                          sizeof(AttentionPush), constants});
    rec.dispatch(kernel, boundArgs, push, static_cast<uint32_t>((gq.rows + queries - 1) / queries),
                 static_cast<uint32_t>(heads), static_cast<uint32_t>(gq.batch));
    return;
  }

  // SwiftShader (KernelPlan::attentionLanesSplitDim): shaders/attention_lanes.comp, a subgroup's
  // lanes splitting the head dimension, for fp32 q, k and v whose heads the lanes divide. 2
  // queries x 4 keys a subgroup, 2 subgroups a workgroup. On SwiftShader (spar-bench, 12 heads x
  // 64, 1280 tokens) 2.2 GFLOPS and 64 ms to compile, against 1.8 and 591 ms for attention.comp's
  // 2 x 4 blocks; the demo request's attention 1.57 -> 1.33 s. 2 x 4 with 4 subgroups and 1 x 4
  // with 2 or 4 ran within 10 % of it (1,4,x slower); 4 x 4, 2 x 8 and 4 x 8 ran out of memory
  // compiling (8 GB).
  if (splitDim) {
    const int queries = 2, keys = 4, subgroups = 2;
    std::vector<int32_t> constants = {lanes, subgroups, 1, headDim, queries, keys, causal ? 1 : 0, lanes};
    withPrep(constants, prep);
    const Kernel& kernel = engine.kernel({"attention_lanes" + prepSuffix + (f16Out ? "_f16out" : "_f32"), binds,
                                          sizeof(AttentionPush), constants, uint32_t(lanes), plan.freezeConstants});
    const int64_t perGroup = int64_t(queries) * subgroups;
    rec.dispatch(kernel, boundArgs, push, static_cast<uint32_t>((gq.rows + perGroup - 1) / perGroup),
                 static_cast<uint32_t>(heads), static_cast<uint32_t>(gq.batch));
    return;
  }

  const bool cpu = plan.cpuShapes;
  // CPU: 8 queries per invocation; blocks of 16 keys for 64-wide heads (spar-bench's case,
  // 20-27 GFLOPS), 8 for narrower ones, which runs as fast there and compiles in 60 % of the
  // time (Mesa 22.3, 32-wide heads: 2.1 s instead of 3.5 s). Mesa 25.0.7 compiles 3x slower:
  // 4 queries per invocation run as fast as 8 there and compile in a third of the time (3.7 s
  // against 11 s); narrower heads take 2 (1.4 s of compile, at 60 % of the speed: attention is
  // about a tenth of the shipped model's compute, its compile a third of the first run).
  // Shared keys (llvmpipe, below): 22.3 about as fast as own keys with the fetches first,
  // 25.0.7 1.6x and half the compile (docs/first-run-and-kernels.md).
  const bool newer = cpu && ops::cpuTiles(engine.caps()) == ops::CpuTiles::Newer;
  const int newerQueries = headDim < 64 ? 2 : 4;
  int queriesPerInvocation = cpu ? (newer ? newerQueries : 8) : 2, keysPerBlock = cpu && headDim < 64 ? 8 : 16;
  // Constants written into the module (SwiftShader, KernelPlan::freezeConstants): the blocks
  // unroll, so they must stay small for its JIT (8 queries of 64-wide heads did not compile in
  // 8 GB). 12 heads x 64, 1280 tokens: 2 x 4 1.6 GFLOPS (0.7 s to compile), 1 x 4 1.0, and 8 x
  // 16 not frozen 1.0.
  const bool frozen = cpu && plan.freezeConstants;
  if (frozen) queriesPerInvocation = 2, keysPerBlock = 4;
  int localX = cpu ? ops::cpuLanes(engine.caps()) : 64;
  if (const auto& t = engine.options().tuning.attentionTiles) {
    queriesPerInvocation = (*t)[0];
    keysPerBlock = (*t)[1];
    localX = (*t)[2];
  }
  // llvmpipe: the workgroup's lanes share each block's keys (attention.comp's SHARED_KEYS).
  const bool sharedKeys = cpu && plan.attentionSharedKeys && keysPerBlock % localX == 0;
  const std::string name = std::string(sharedKeys ? "attention_sk" : "attention") + prepSuffix + (f16Out ? "_f16out" : "_f32");
  std::vector<int32_t> constants = {localX, 1, 1, headDim, queriesPerInvocation, keysPerBlock, causal ? 1 : 0, localX};
  withPrep(constants, prep);
  const Kernel& kernel = engine.kernel({name, binds, sizeof(AttentionPush), constants, sharedKeys ? uint32_t(localX) : 0u,
                                        frozen});
  const int64_t perGroup = int64_t(queriesPerInvocation) * localX;
  rec.dispatch(kernel, boundArgs, push, static_cast<uint32_t>((gq.rows + perGroup - 1) / perGroup),
               static_cast<uint32_t>(heads), static_cast<uint32_t>(gq.batch));
}

}  // namespace spar
