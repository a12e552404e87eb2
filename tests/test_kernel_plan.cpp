// The kernel choice per device (engine/kernel_plan.h, engine/kernel_tuner.h): which family a
// device's properties select, the forced families, the measured GEMM tiles and their cache file,
// and the fp16-arithmetic GEMM of the GPU family against float64 (its own thresholds).
// The GPU kernels themselves run every op test a second time (CTest entries gpu_family.*, the
// op executables under SPAR_KERNELS=gpu); cooperative matrices: tests/coopmat/.
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "engine/kernel_plan.h"
#include "engine/kernel_tuner.h"
#include "engine/ops/attention.h"
#include "engine/ops/linear.h"
#include "engine/ops/row_padding.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;

DeviceCaps gpuCaps() {
  DeviceCaps c;
  c.name = "Test GPU";
  c.type = VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU;
  c.subgroupSize = c.minSubgroupSize = c.maxSubgroupSize = 32;
  c.subgroupArithmetic = true;
  c.maxSharedMemory = 48 * 1024;
  c.maxWorkGroupInvocations = 1024;
  return c;
}

DeviceCaps cpuCaps() {
  DeviceCaps c = gpuCaps();
  c.name = "llvmpipe";
  c.type = VK_PHYSICAL_DEVICE_TYPE_CPU;
  c.subgroupSize = c.minSubgroupSize = c.maxSubgroupSize = 8;
  return c;
}

TEST(KernelPlan, CpuDeviceGetsRegisterBlocks) {
  const KernelPlan p = planKernels(cpuCaps(), {});
  EXPECT_EQ(p.gemm, KernelFamily::CpuBlocks);
  EXPECT_EQ(p.gemmF16, KernelFamily::CpuBlocks);
  EXPECT_EQ(p.attention, KernelFamily::CpuBlocks);
  EXPECT_EQ(p.conv, KernelFamily::CpuBlocks);
  EXPECT_TRUE(p.cpuShapes);
  EXPECT_FALSE(p.subgroupReductions);
  EXPECT_FALSE(p.measureTiles);
}

// llvmpipe shares a GEMM workgroup's columns among its subgroup's lanes (engine/ops/linear.cpp):
// 4 x 16, 4 x 32 from 2^28 multiply-adds; Mesa 25's below 2^28 keep register blocks (compile).
// Only with shuffles and full subgroups of the lanes' size, and never where the tiles are forced
// or on another CPU driver, whose kernels were not measured so.
TEST(KernelPlan, LlvmpipeSharesColumnsByDriverAndProduct) {
  DeviceCaps c = cpuCaps();
  c.driverId = VK_DRIVER_ID_MESA_LLVMPIPE;
  c.mesaMajor = 22;
  c.subgroupShuffle = c.fullSubgroups = true;
  const double large = double(1 << 28), small = large / 2;
  GemmTiles t = chooseGemmTiles(c, {}, large, 1003);
  EXPECT_TRUE(t.sharedColumns);
  EXPECT_EQ(t.rowsPerInvocation, 4);
  EXPECT_EQ(t.colsPerInvocation, 32);
  EXPECT_EQ(t.localX, 8);
  EXPECT_EQ(t.localY, 1);
  EXPECT_EQ(chooseGemmTiles(c, {}, large, 20).colsPerInvocation, 16);
  t = chooseGemmTiles(c, {}, small, 1003);
  EXPECT_TRUE(t.sharedColumns);
  EXPECT_EQ(t.colsPerInvocation, 16);
  DeviceCaps newer = c;
  newer.mesaMajor = 25;
  EXPECT_FALSE(chooseGemmTiles(newer, {}, small, 1003).sharedColumns);
  EXPECT_TRUE(chooseGemmTiles(newer, {}, large, 1003).sharedColumns);
  KernelTuning forced;
  forced.gemmTiles = std::array<int, 5>{4, 16, 8, 8, 2};
  EXPECT_FALSE(chooseGemmTiles(c, forced, large, 1003).sharedColumns);
  for (auto lacks : {&DeviceCaps::subgroupShuffle, &DeviceCaps::fullSubgroups}) {
    DeviceCaps d = c;
    d.*lacks = false;
    EXPECT_FALSE(chooseGemmTiles(d, {}, large, 1003).sharedColumns);
  }
  DeviceCaps swiftshader = c;
  swiftshader.driverId = VK_DRIVER_ID_GOOGLE_SWIFTSHADER;
  swiftshader.mesaMajor = 0;
  EXPECT_FALSE(chooseGemmTiles(swiftshader, {}, large, 1003).sharedColumns);
  // The plan says so (spar-bench --list-kernels), and not where the tiles are forced.
  const KernelPlan plan = planKernels(c, {});
  EXPECT_TRUE(plan.gemmSharedColumns && plan.attentionSharedKeys);
  auto lists = [&](const KernelPlan& p, const std::string& what) {
    for (const auto& line : describePlan(p, c))
      if (line.find(what) != std::string::npos) return true;
    return false;
  };
  EXPECT_TRUE(lists(plan, "columns shared by the subgroup's lanes"));
  EXPECT_TRUE(lists(plan, "keys shared by the subgroup's lanes"));
  KernelTuning all = forced;
  all.attentionTiles = std::array<int, 3>{8, 16, 8};
  all.convTiles = std::array<int, 5>{8, 1, 8, 8, 1};
  const KernelPlan forcedPlan = planKernels(c, all);
  EXPECT_FALSE(forcedPlan.gemmSharedColumns || forcedPlan.attentionSharedKeys || forcedPlan.convSharedWeights);
  EXPECT_FALSE(lists(forcedPlan, "shared by the subgroup's lanes"));
  DeviceCaps wide = c;  // 512-bit llvmpipe: 16 lanes share 16 or 32 columns (multiples of them)
  wide.subgroupSize = wide.minSubgroupSize = wide.maxSubgroupSize = 16;
  EXPECT_EQ(chooseGemmTiles(wide, {}, large, 1003).localX, 16);
  EXPECT_TRUE(chooseGemmTiles(wide, {}, large, 20).sharedColumns);
}

// Transformer MLPs' hidden rows are widened where they alias in a CPU's L1 cache
// (engine/ops/row_padding.h): the CPU family with gemm.comp, not SwiftShader's lanes GEMM, not
// GPUs; SPAR_ROW_PADDING forces either way on a CPU plan.
TEST(KernelPlan, AliasedRowsPaddedWhereGemmCompReadsThem) {
  DeviceCaps c = cpuCaps();
  c.driverId = VK_DRIVER_ID_MESA_LLVMPIPE;
  c.mesaMajor = 22;
  const KernelPlan plan = planKernels(c, {});
  EXPECT_TRUE(plan.padAliasedRows);
  EXPECT_EQ(ops::unaliasedRow(plan, 3072), 3076);  // 12288 bytes: every row in one set
  EXPECT_EQ(ops::unaliasedRow(plan, 1536), 1540);  // 6144: two sets
  EXPECT_EQ(ops::unaliasedRow(plan, 512), 516);
  EXPECT_EQ(ops::unaliasedRow(plan, 768), 768);    // 3072: four sets, measured within 3 %
  EXPECT_EQ(ops::unaliasedRow(plan, 256), 256);
  EXPECT_EQ(ops::unaliasedRow(plan, 0), 0);
  DeviceCaps swiftshader = c;
  swiftshader.driverId = VK_DRIVER_ID_GOOGLE_SWIFTSHADER;
  swiftshader.mesaMajor = 0;
  swiftshader.subgroupArithmetic = swiftshader.fullSubgroups = true;
  const KernelPlan ss = planKernels(swiftshader, {});
  ASSERT_TRUE(ss.gemmLanesSplitK);
  EXPECT_FALSE(ss.padAliasedRows);
  EXPECT_EQ(ops::unaliasedRow(ss, 3072), 3072);
  EXPECT_FALSE(planKernels(gpuCaps(), {}).padAliasedRows);
  KernelTuning off, on;
  off.padAliasedRows = false;
  on.padAliasedRows = true;
  EXPECT_FALSE(planKernels(c, off).padAliasedRows);
  EXPECT_TRUE(planKernels(swiftshader, on).padAliasedRows);
  auto lists = [&](const KernelPlan& p, const std::string& what) {
    for (const auto& line : describePlan(p, c))
      if (line.find(what) != std::string::npos) return true;
    return false;
  };
  EXPECT_TRUE(lists(plan, "hidden rows 4 elements wider"));
  EXPECT_TRUE(lists(planKernels(c, off), "hidden rows: as the model has them: forced (SPAR_ROW_PADDING)"));
}

// conv2d's weights are shared by the lanes where that measured faster: Mesa 22.3 at 8 and 16
// lanes, not Mesa 25 (engine/kernel_plan.cpp), never where the conv tiles are forced.
TEST(KernelPlan, LlvmpipeSharesConvWeightsOnMesa22) {
  DeviceCaps c = cpuCaps();
  c.driverId = VK_DRIVER_ID_MESA_LLVMPIPE;
  c.mesaMajor = 22;
  c.subgroupShuffle = c.fullSubgroups = true;
  const KernelPlan plan = planKernels(c, {});
  EXPECT_TRUE(plan.convSharedWeights);
  bool listed = false;
  for (const auto& line : describePlan(plan, c)) listed |= line.find("weights shared by the subgroup's lanes") != std::string::npos;
  EXPECT_TRUE(listed);
  DeviceCaps wide = c;
  wide.subgroupSize = wide.minSubgroupSize = wide.maxSubgroupSize = 16;
  EXPECT_TRUE(planKernels(wide, {}).convSharedWeights);
  DeviceCaps newer = c;
  newer.mesaMajor = 25;
  EXPECT_FALSE(planKernels(newer, {}).convSharedWeights);
  EXPECT_TRUE(planKernels(newer, {}).gemmSharedColumns);
  KernelTuning forced;
  forced.convTiles = std::array<int, 5>{8, 1, 8, 8, 1};
  EXPECT_FALSE(planKernels(c, forced).convSharedWeights);
  EXPECT_TRUE(planKernels(c, forced).gemmSharedColumns);
  DeviceCaps noShuffle = c;
  noShuffle.subgroupShuffle = false;
  EXPECT_FALSE(planKernels(noShuffle, {}).convSharedWeights);
}

// Mesa 22.3 and 25.0.7 reuse shaders built at another LP_NATIVE_VECTOR_WIDTH (their cache keys
// leave it out), 26.1 does not: the device banner warns whoever measures the former at a width.
TEST(KernelPlan, ShaderCacheSharedAcrossVectorWidthsBeforeMesa26) {
  DeviceCaps c = cpuCaps();
  EXPECT_FALSE(c.shaderCacheIgnoresVectorWidth());  // not llvmpipe
  c.driverId = VK_DRIVER_ID_MESA_LLVMPIPE;
  for (const auto& [mesa, shared] : {std::pair{22u, true}, {25u, true}, {26u, false}, {0u, false}}) {
    c.mesaMajor = mesa;
    EXPECT_EQ(c.shaderCacheIgnoresVectorWidth(), shared) << "Mesa " << mesa;
  }
}

TEST(KernelPlan, GpuGetsTilesSubgroupsAndMeasuredGemm) {
  const KernelPlan p = planKernels(gpuCaps(), {});
  EXPECT_EQ(p.gemm, KernelFamily::Tiled);
  EXPECT_EQ(p.gemmF16, KernelFamily::Tiled);  // no fp16 arithmetic, no cooperative matrices
  EXPECT_FALSE(p.fp16Math);
  EXPECT_EQ(p.attention, KernelFamily::Tiled);
  EXPECT_EQ(p.conv, KernelFamily::Tiled);
  EXPECT_FALSE(p.cpuShapes);
  EXPECT_TRUE(p.subgroupReductions);
  EXPECT_TRUE(p.measureTiles);
  DeviceCaps noSubgroups = gpuCaps();
  noSubgroups.subgroupArithmetic = false;
  EXPECT_FALSE(planKernels(noSubgroups, {}).subgroupReductions);
}

TEST(KernelPlan, Fp16WeightsUseCoopMatThenFp16Arithmetic) {
  DeviceCaps c = gpuCaps();
  c.shaderFloat16 = true;
  KernelPlan p = planKernels(c, {});
  EXPECT_EQ(p.gemmF16, KernelFamily::Tiled);
  EXPECT_TRUE(p.fp16Math);
  // Sizes the kernel cannot use (int8, fp16 accumulation, 64 wide) are passed over; 16^3 wins.
  c.coopMatSizes = {{16, 8, 32, 3, 3, 5, 5}, {16, 16, 16, 0, 0, 0, 0}, {64, 64, 64, 0, 0, 1, 1},
                    {16, 8, 16, 0, 0, 1, 1}, {16, 16, 16, 0, 0, 1, 1}};
  c.cooperativeMatrix = true;
  p = planKernels(c, {});
  EXPECT_EQ(p.gemmF16, KernelFamily::CoopMat);
  EXPECT_EQ(p.gemm, KernelFamily::Tiled);  // fp32 weights never lose precision to fp16
  EXPECT_EQ(p.coop.m, 16);
  EXPECT_EQ(p.coop.n, 16);
  EXPECT_EQ(p.coop.k, 16);
  c.coopMatSizes = {{16, 8, 16, 0, 0, 1, 1}};
  EXPECT_EQ(planKernels(c, {}).coop.n, 8);
  // A forced workgroup shape is checked against the device (shared memory, invocations), not
  // left to fail in the driver; it also turns measuring off.
  c.coopMatSizes = {{16, 16, 16, 0, 0, 1, 1}};
  KernelTuning t;
  t.coopMatTiles = std::array<int, 6>{4, 2, 2, 2, 2, 1};
  p = planKernels(c, t);
  EXPECT_EQ(p.coop.wm, 4);
  EXPECT_FALSE(p.measureTiles);
  EXPECT_LE(p.coop.sharedBytes(), c.maxSharedMemory);
  t.coopMatTiles = std::array<int, 6>{8, 8, 4, 4, 8, 1};  // 512x512 outputs, k step 128: far past 48 KiB
  EXPECT_THROW(planKernels(c, t), Error);
}

TEST(KernelPlan, ForcedFamilies) {
  KernelTuning t;
  t.kernels = "cpu";
  EXPECT_EQ(planKernels(gpuCaps(), t).gemm, KernelFamily::CpuBlocks);
  t.kernels = "gpu";
  const KernelPlan g = planKernels(cpuCaps(), t);
  EXPECT_EQ(g.gemm, KernelFamily::Tiled);
  EXPECT_FALSE(g.cpuShapes);
  EXPECT_FALSE(g.measureTiles);  // a CPU device measures only when asked
  t.kernels = "coopmat";
  EXPECT_THROW(planKernels(gpuCaps(), t), Error);
  t.kernels = "gpu-fp16";
  EXPECT_THROW(planKernels(gpuCaps(), t), Error);
  DeviceCaps h = gpuCaps();
  h.shaderFloat16 = true;
  EXPECT_TRUE(planKernels(h, t).fp16Math);
  t.kernels = "vulkan";
  EXPECT_THROW(t.validate(), Error);
  t.kernels = "gpu";
  t.gpuGemmTiles = std::array<int, 6>{64, 32, 8, 4, 2, 1};
  const KernelPlan forced = planKernels(gpuCaps(), t);
  EXPECT_EQ(forced.gemmTiles, (TiledGemmTiles{64, 32, 8, 4, 2}));
  EXPECT_FALSE(forced.measureTiles);
  t.gpuGemmTiles = std::array<int, 6>{64, 32, 6, 4, 2, 1};  // BK not a multiple of 4
  EXPECT_THROW(t.validate(), Error);
}

// NVIDIA's driver (seen on an H200, 2026-12-04): 2^27 texels a texel buffer, 4 GiB a storage
// binding, so inputs go through storage buffers; the first run there found the *_sx twins of the
// cooperative-matrix kernels missing and fp16 weights refused. SPAR_INPUTS forces either way.
TEST(KernelPlan, StorageInputsWhereTexelBuffersAreShorterThanStorage) {
  DeviceCaps nv = gpuCaps();
  nv.maxTexelBufferElements = 1ull << 27;
  nv.maxStorageBufferRange = (4ull << 30) - 1;
  EXPECT_TRUE(planKernels(nv, {}).storageInputs);
  DeviceCaps lavapipe = cpuCaps();
  lavapipe.maxTexelBufferElements = 1ull << 27;
  lavapipe.maxStorageBufferRange = 1ull << 27;
  EXPECT_FALSE(planKernels(lavapipe, {}).storageInputs);
  KernelTuning t;
  t.inputs = "storage";
  EXPECT_TRUE(planKernels(lavapipe, t).storageInputs);
  t.inputs = "texel";
  const KernelPlan texel = planKernels(nv, t);
  EXPECT_FALSE(texel.storageInputs);
  const auto lines = describePlan(texel, nv);
  EXPECT_TRUE(std::any_of(lines.begin(), lines.end(), [](const std::string& l) { return l == "inputs: texel buffers"; }));
  EXPECT_TRUE(std::any_of(lines.begin(), lines.end(),
                          [](const std::string& l) { return l.find("forced (SPAR_INPUTS=texel)") != std::string::npos; }));
  t.inputs = "ssbo";
  EXPECT_THROW(t.validate(), Error);
}

TEST(KernelPlan, DescribeSaysWhatAndWhy) {
  DeviceCaps c = gpuCaps();
  c.cooperativeMatrix = true;
  c.coopMatSizes = {{16, 16, 16, 0, 0, 1, 1}};
  const auto lines = describePlan(planKernels(c, {}), c);
  std::string all;
  for (const auto& l : lines) all += l + "\n";
  EXPECT_NE(all.find("16x16x16 f16*f16+f32"), std::string::npos) << all;
  EXPECT_NE(all.find("linear, fp16 weights: gemm_coopmat.comp"), std::string::npos) << all;
  EXPECT_NE(all.find("attention: attention_flash.comp (32 queries a workgroup, 32-key blocks, 16 invocations"), std::string::npos) << all;
  EXPECT_NE(all.find("why: "), std::string::npos) << all;
}

TEST(KernelPlan, SmallProductsGetSmallTiles) {
  KernelPlan p = planKernels(gpuCaps(), {});
  EXPECT_EQ(p.tilesFor(4096, 4096, 1), p.gemmTiles);
  EXPECT_EQ(p.tilesFor(64, 768, 1), p.gemmSmallTiles);
}

// On a CPU device forced onto the GPU family and asked to measure: GEMM tiles (on a transformer
// block's four products) and attention blocks are measured once, written beside the pipeline cache, and read back by the next
// engine without measuring.
TEST(KernelTuner, MeasuresOnceThenReadsTheCacheFile) {
  const fs::path dir = scratchDir("kernel_tuner");
  EngineOptions o;
  o.validation = true;
  o.tuning.kernels = "gpu";
  o.tuning.measureKernels = true;
  o.pipelineCacheFile = (dir / "pipelines.bin").string();
  const std::string file = kernelChoiceFile(o.pipelineCacheFile);
  EXPECT_EQ(fs::path(file).filename(), "kernel-choice.json");
  std::string first;
  {
    Engine e(o);
    const KernelPlan& p = e.plan();
    EXPECT_NE(p.source.find("measured now"), std::string::npos) << p.source;
    first = p.gemmTiles.text();
    EXPECT_EQ(e.device().validationMessageCount(), 0u);
  }
  ASSERT_TRUE(fs::exists(file));
  std::ifstream in(file);
  const auto j = nlohmann::json::parse(in);
  ASSERT_EQ(j.size(), 1u);
  const auto& entry = j.begin().value();
  // the GEMM tiles timed on a transformer block's products (the model's aspect ratios), not a square
  EXPECT_NE(entry["gemm"]["workload"].get<std::string>().find("block"), std::string::npos) << entry.dump();
  for (const char* what : {"gemm", "attention"}) {
    EXPECT_GE(entry[what]["candidates"].size(), 3u) << what;
    for (const auto& c : entry[what]["candidates"]) EXPECT_GT(c["ms"].get<double>(), 0.0) << what;
  }
  {
    Engine e(o);
    const KernelPlan& p = e.plan();
    EXPECT_NE(p.source.find("kernel-choice.json"), std::string::npos) << p.source;
    EXPECT_EQ(p.gemmTiles.text(), first);
    EXPECT_EQ(std::vector<int>({p.attentionQueries, p.attentionKeys, p.attentionLanes}), entry["attention"]["tiles"].get<std::vector<int>>());
  }
}

// Every GEMM tile and attention block the tuner tries (engine/kernel_tuner.h), forced in turn
// on the GPU family, computes the same results (odd sizes: every tile has edges).
TEST_F(EngineTest, EveryMeasuredCandidateComputesTheSame) {
  ScopedKernels family(eng(), "gpu");
  const KernelTuning saved = eng().options().tuning;
  const int64_t M = 77, N = 150, K = 72;
  auto x = randomUniform(M * K, -1, 1, 61), w = randomUniform(N * K, -1, 1, 62);
  Tensor tx = eng().fromFloats({M, K}, x), tw = eng().fromFloats({N, K}, w);
  const auto ref = linearRef(x, w, {}, 1, M, N, K, false, Activation::None);
  const auto gemms = gemmTileCandidates(eng().caps());
  ASSERT_GE(gemms.size(), 3u);
  for (const TiledGemmTiles& c : gemms) {
    KernelTuning t = saved;
    t.gpuGemmTiles = std::array<int, 6>{c.bm, c.bn, c.bk, c.tm, c.tn, c.pipelined};
    eng().setTuning(t);
    GuardedOutput y(eng(), {M, N});
    Recorder rec(eng());
    linear(rec, tx, tw, Tensor(), y.tensor());
    rec.run();
    expectClose(y.read(), ref, 1e-10, 1e-4, "gemm " + c.text());
    y.expectAllWritten();
  }
  const int heads = 2, dh = 64;
  const int64_t T = 93, D = heads * dh;
  auto qkv = randomNormal(T * 3 * D, 0, 1, 63);
  Tensor tq = eng().fromFloats({1, T, 3 * D}, qkv);
  const auto aref = attentionRef(qkv, 3 * D, 0, qkv, 3 * D, D, qkv, 3 * D, 2 * D, 1, T, T, heads, dh, false, 0.125);
  const auto blocks = attentionBlockCandidates(eng().caps());
  ASSERT_GE(blocks.size(), 3u);
  for (const auto& b : blocks) {
    KernelTuning t = saved;
    t.gpuAttentionTiles = b;
    eng().setTuning(t);
    GuardedOutput o(eng(), {1, T, D});
    Recorder rec(eng());
    attention(rec, {tq, 0}, {tq, D}, {tq, 2 * D}, {o.tensor(), 0}, heads, dh);
    rec.run();
    expectClose(o.read(), aref, 1e-9, 1e-4, "attention " + std::to_string(b[0]) + "/" + std::to_string(b[1]) + "/" + std::to_string(b[2]));
    o.expectAllWritten();
  }
  eng().setTuning(saved);
}

// gemm_tiled.comp with FP16_MATH (SPAR_KERNELS=gpu-fp16 on any device with shaderFloat16):
// inputs rounded to fp16 and 4-term partial sums in fp16, accumulated in fp32. Against float64
// on the fp16-rounded inputs the error is the partials' rounding (measured NMSE 1.6e-7 at
// K = 384, 2.0e-7 at K = 61 through R texels; thresholds 1e-6), and saturation instead of inf.
class Fp16MathTest : public EngineTest {
 protected:
  ScopedKernels family_{eng(), "gpu-fp16"};
};

TEST_F(Fp16MathTest, MatchesFloat64WithinFp16Partials) {
  ASSERT_TRUE(eng().plan().fp16Math);
  for (const auto [M, N, K] : {std::array<int64_t, 3>{45, 70, 384}, {33, 17, 61}, {1, 1, 4}}) {
    auto x = randomUniform(M * K, -1, 1, 21), w = randomUniform(N * K, -1, 1, 22), b = randomUniform(N, -1, 1, 23);
    Tensor tx = eng().fromFloats({M, K}, x), tw = eng().fromFloats({N, K}, w, DType::F16);
    Tensor tb = eng().fromFloats({N}, b);
    GuardedOutput y(eng(), {M, N});
    Recorder rec(eng());
    linear(rec, tx, tw, tb, y.tensor());
    rec.run();
    expectClose(y.read(), linearRef(roundToHalf(x), roundToHalf(w), b, 1, M, N, K, false, Activation::None), 1e-6, 2e-2, "fp16 math");
    y.expectAllWritten();
  }
}

// A 4-term partial beyond 65504 saturates (the fp32 sum of two of them is then 131008, not inf).
TEST_F(Fp16MathTest, PartialOverflowSaturates) {
  const int64_t M = 2, N = 3, K = 8;
  std::vector<float> x(M * K, 200.0f), w(N * K, 100.0f);  // each product 20000, 4 of them 80000
  Tensor tx = eng().fromFloats({M, K}, x), tw = eng().fromFloats({N, K}, w, DType::F16);
  GuardedOutput y(eng(), {M, N});
  Recorder rec(eng());
  linear(rec, tx, tw, Tensor(), y.tensor());
  rec.run();
  for (float v : y.read()) EXPECT_EQ(v, 2 * 65504.0f);
}

}  // namespace
}  // namespace spar::test
