// The Vulkan runtime itself: device choice, memory, recorder barriers, profiling,
// validation plumbing, fp16 conversion, specialization constants frozen into a module.
#include <cstring>
#include <map>

#include "engine/engine.h"
#include "engine/half.h"
#include "engine/ops/linear.h"
#include "engine/shader_registry.h"
#include "engine/spirv_freeze.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

TEST(Runtime, ListsAtLeastOneDevice) {
  auto devices = Device::listDevices();
  ASSERT_FALSE(devices.empty());
  EXPECT_EQ(devices[0].rfind("0: ", 0), 0u) << devices[0];
}

TEST(Runtime, UnknownDeviceNameIsAClearError) {
  DeviceOptions options;
  options.select = "no-such-gpu-xyz";
  try {
    Device device(options);
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("no Vulkan device matches 'no-such-gpu-xyz'"), std::string::npos) << e.what();
  }
}

TEST(Runtime, DeviceChosenByIndexAndByName) {
  DeviceOptions byIndex;
  byIndex.select = "0";
  Device a(byIndex);
  DeviceOptions byName;
  byName.select = a.caps().name.substr(0, 4);
  Device b(byName);
  EXPECT_EQ(a.caps().name.substr(0, 4), b.caps().name.substr(0, 4));
}

// Synchronization validation is on with validation: two transfer writes to one buffer with
// no barrier between them are a write-after-write hazard, and the layer reports it.
TEST(Runtime, SynchronizationHazardsAreReported) {
  EngineOptions options;
  options.validation = true;
  Engine engine(options);
  Tensor t = engine.tensor({64});
  VkDevice dev = engine.device().handle();
  VkCommandPoolCreateInfo poolInfo{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
  poolInfo.queueFamilyIndex = engine.device().queueFamily();
  VkCommandPool pool = VK_NULL_HANDLE;
  ASSERT_EQ(vkCreateCommandPool(dev, &poolInfo, nullptr, &pool), VK_SUCCESS);
  VkCommandBufferAllocateInfo alloc{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
  alloc.commandPool = pool;
  alloc.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  alloc.commandBufferCount = 1;
  VkCommandBuffer cmd = VK_NULL_HANDLE;
  ASSERT_EQ(vkAllocateCommandBuffers(dev, &alloc, &cmd), VK_SUCCESS);
  VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  ASSERT_EQ(vkBeginCommandBuffer(cmd, &begin), VK_SUCCESS);
  const size_t before = engine.device().validationMessageCount();
  std::fprintf(stderr, "(the next validation message, a SYNC-HAZARD-WRITE-AFTER-WRITE, is expected)\n");
  vkCmdFillBuffer(cmd, t.buffer().handle(), 0, 256, 1u);
  vkCmdFillBuffer(cmd, t.buffer().handle(), 0, 256, 2u);
  EXPECT_GT(engine.device().validationMessageCount(), before);
  vkEndCommandBuffer(cmd);
  vkDestroyCommandPool(dev, pool, nullptr);
}

// The messenger counts what the layer reports: a buffer of size 0 is invalid usage.
TEST(Runtime, ValidationMessagesAreCounted) {
  DeviceOptions options;
  options.validation = true;
  Device device(options);
  EXPECT_EQ(device.validationMessageCount(), 0u);
  VkBufferCreateInfo info{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
  info.size = 0;
  info.usage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
  VkBuffer buffer = VK_NULL_HANDLE;
  std::fprintf(stderr, "(the next validation message is expected)\n");
  if (vkCreateBuffer(device.handle(), &info, nullptr, &buffer) == VK_SUCCESS && buffer)
    vkDestroyBuffer(device.handle(), buffer, nullptr);
  EXPECT_GE(device.validationMessageCount(), 1u);
}

TEST_F(EngineTest, AllocatorReusesAndCoalescesFreedRanges) {
  MemoryAllocator& mem = eng().memory();
  const VkDeviceSize inUseBefore = mem.bytesInUse();
  VkDeviceSize reservedBefore = 0;
  {
    std::vector<Tensor> tensors;
    for (int i = 0; i < 20; ++i) tensors.push_back(eng().tensor({1000 + i * 37}));
    EXPECT_GT(mem.bytesInUse(), inUseBefore);
    reservedBefore = mem.bytesReserved();
  }
  EXPECT_EQ(mem.bytesInUse(), inUseBefore);
  // After the 20 small ranges were freed and coalesced, one tensor as large as all of
  // them together fits without a new block.
  Tensor big = eng().tensor({20 * 1400});
  EXPECT_EQ(mem.bytesReserved(), reservedBefore);
}

TEST_F(EngineTest, ViewsShareTheirBuffer) {
  auto values = randomUniform(64, -1, 1, 40);
  Tensor t = eng().fromFloats({8, 8}, values);
  Tensor row3 = t.view(24, {8});
  auto got = eng().download(row3);
  for (int i = 0; i < 8; ++i) EXPECT_EQ(got[i], values[24 + i]);
  EXPECT_THROW(t.view(60, {8}), Error);
  EXPECT_THROW(t.reshape({7, 8}), Error);
}

// 40 dependent linear layers in one submission: each reads what the previous wrote, so
// a missing barrier shows up as a wrong result.
TEST_F(EngineTest, RecorderOrdersDependentDispatches) {
  const int64_t M = 33, D = 24;
  const int layers = 40;
  auto x = randomUniform(M * D, -1, 1, 41);
  auto w = randomUniform(D * D, -1.0f, 1.0f, 42);
  Tensor tw = eng().fromFloats({D, D}, w);
  std::vector<Tensor> acts = {eng().fromFloats({M, D}, x)};
  Recorder rec(eng(), true);
  for (int l = 0; l < layers; ++l) {
    acts.push_back(eng().tensor({M, D}));
    linear(rec, acts[l], tw, Tensor(), acts[l + 1], Activation::Sigmoid);
  }
  EXPECT_EQ(rec.pending(), size_t(layers));
  rec.run();
  std::vector<double> ref(x.begin(), x.end()), next(M * D);
  for (int l = 0; l < layers; ++l) {
    for (int64_t m = 0; m < M; ++m)
      for (int64_t n = 0; n < D; ++n) {
        double s = 0;
        for (int64_t k = 0; k < D; ++k) s += ref[m * D + k] * w[n * D + k];
        next[m * D + n] = 1 / (1 + std::exp(-s));
      }
    ref.swap(next);
  }
  expectClose(eng().download(acts.back()), ref, 1e-9, 1e-5, "40 chained layers");
  // Profiling: one timing per dispatch, labelled, non-negative.
  ASSERT_EQ(rec.timings().size(), size_t(layers));
  for (const auto& t : rec.timings()) {
    EXPECT_GE(t.ms, 0.0);
    EXPECT_NE(t.label.find("gemm"), std::string::npos) << t.label;
  }
  EXPECT_GT(rec.totalMs(), 0.0);
}

// Barriers go exactly where a dispatch touches what an earlier one wrote (read after
// write, write after read, write after write), and nowhere else.
TEST_F(EngineTest, RecorderInsertsBarriersOnlyForHazards) {
  Tensor w = eng().fromFloats({4, 4}, randomUniform(16, -1, 1, 45));
  Tensor a = eng().fromFloats({4, 4}, randomUniform(16, -1, 1, 46));
  Tensor b = eng().tensor({4, 4}), c = eng().tensor({4, 4}), d = eng().tensor({4, 4});
  Recorder rec(eng());
  linear(rec, a, w, Tensor(), b);  // writes b
  linear(rec, a, w, Tensor(), c);  // independent of the first: no barrier
  EXPECT_EQ(rec.barriers(), 0u);
  linear(rec, b, w, Tensor(), d);  // reads b: read after write
  EXPECT_EQ(rec.barriers(), 1u);
  linear(rec, a, w, Tensor(), b);  // writes b, which the previous dispatch read: write after read
  EXPECT_EQ(rec.barriers(), 2u);
  linear(rec, a, w, Tensor(), b);  // writes b again: write after write
  EXPECT_EQ(rec.barriers(), 3u);
  rec.run();
  EXPECT_EQ(rec.barriers(), 0u);
}

TEST_F(EngineTest, RecorderIsReusableAfterRun) {
  auto x = randomUniform(16, -1, 1, 43), w = randomUniform(16, -1, 1, 44);
  Tensor tx = eng().fromFloats({4, 4}, x), tw = eng().fromFloats({4, 4}, w), ty = eng().tensor({4, 4});
  Recorder rec(eng());
  for (int round = 0; round < 3; ++round) {
    linear(rec, tx, tw, Tensor(), ty);
    rec.run();
    EXPECT_EQ(rec.pending(), 0u);
  }
  auto y = eng().download(ty);
  double s = 0;
  for (int k = 0; k < 4; ++k) s += double(x[k]) * w[k];
  EXPECT_NEAR(y[0], s, 1e-6);
}

TEST_F(EngineTest, UploadChecksSizes) {
  Tensor t = eng().tensor({10});
  std::vector<float> wrong(9);
  EXPECT_THROW(eng().upload(t, wrong), Error);
}

TEST_F(EngineTest, Fp16UploadSaturatesBeyondRange) {
  if (!eng().caps().supportsFp16Storage()) GTEST_SKIP() << "device without fp16 storage";
  std::vector<float> v = {1e5f, -7e4f, 65504.0f, 65519.0f, 1.0f};
  Tensor t = eng().fromFloats({5}, v, DType::F16);
  auto got = eng().download(t);
  EXPECT_EQ(got[0], 65504.0f);
  EXPECT_EQ(got[1], -65504.0f);
  EXPECT_EQ(got[2], 65504.0f);
  EXPECT_EQ(got[3], 65504.0f);
  EXPECT_EQ(got[4], 1.0f);
}

TEST(Half, EveryHalfRoundTripsThroughFloat) {
  for (uint32_t h = 0; h < 65536; ++h) {
    const float f = halfToFloat(uint16_t(h));
    if (std::isnan(f)) {
      EXPECT_TRUE(std::isnan(halfToFloat(floatToHalf(f))));
      continue;
    }
    ASSERT_EQ(floatToHalf(f), h) << "half 0x" << std::hex << h;
  }
}

TEST(Half, RoundsToNearestEven) {
  EXPECT_EQ(halfToFloat(floatToHalf(1.0f + 1.0f / 2048)), 1.0f);                 // tie: down to even
  EXPECT_EQ(halfToFloat(floatToHalf(1.0f + 3.0f / 2048)), 1.0f + 4.0f / 2048);   // tie: up to even
  EXPECT_EQ(halfToFloat(floatToHalf(5.9604645e-8f)), 5.9604645e-8f);             // smallest subnormal
  EXPECT_EQ(halfToFloat(floatToHalf(2.9e-8f)), 0.0f);                            // below half of it
  EXPECT_TRUE(std::isinf(halfToFloat(floatToHalf(65520.0f))));                   // IEEE: overflow to inf
  EXPECT_EQ(halfToFloat(floatToHalf(65519.0f)), 65504.0f);
}

// Each instruction of a module by its result id (types and constants have it at word 2).
struct SpirvConstants {
  std::map<uint32_t, uint32_t> specIdOf;                   // result id -> SpecId
  std::map<uint32_t, std::vector<uint32_t>> instruction;   // result id -> its words (constants only)
  int specConstants = 0;
};
SpirvConstants readConstants(std::span<const uint32_t> m) {
  SpirvConstants out;
  for (size_t i = 5; i < m.size(); i += m[i] >> 16) {
    const uint32_t op = m[i] & 0xFFFF, n = m[i] >> 16;
    if (op == 71 && n == 4 && m[i + 2] == 1) out.specIdOf[m[i + 1]] = m[i + 3];  // OpDecorate SpecId
    if (op >= 41 && op <= 43) out.instruction[m[i + 2]] = {m.begin() + i, m.begin() + i + n};
    if (op >= 48 && op <= 50) {
      out.instruction[m[i + 2]] = {m.begin() + i, m.begin() + i + n};
      ++out.specConstants;
    }
  }
  return out;
}

// engine/spirv_freeze.h on a real kernel: gemm_lanes.comp's RM (SpecId 3, int), HAS_BIAS
// (7, bool) given values, RN (4) left at its default 8; no specialization constant or SpecId
// left. (Run on devices in test_linear's LinearLanesSplitKMatchesFloat64, where the validation
// layer checks the modules.)
TEST(SpirvFreeze, WritesTheValuesAndDropsTheSpecIds) {
  const std::span<const uint32_t> module = findShader("gemm_lanes_f32");
  const SpirvConstants before = readConstants(module);
  ASSERT_GT(before.specConstants, 5);
  std::map<uint32_t, uint32_t> idOfSpec;
  for (const auto& [id, spec] : before.specIdOf) idOfSpec[spec] = id;
  ASSERT_TRUE(idOfSpec.count(3) && idOfSpec.count(4) && idOfSpec.count(7));

  const std::vector<uint32_t> frozen = freezeSpecConstants(module, {{3, 5}, {7, 1}, {60, 9}});
  const SpirvConstants after = readConstants(frozen);
  EXPECT_EQ(after.specConstants, 0);
  EXPECT_TRUE(after.specIdOf.empty());
  EXPECT_EQ(after.instruction.at(idOfSpec[3]), (std::vector<uint32_t>{(4u << 16) | 43, before.instruction.at(idOfSpec[3])[1], idOfSpec[3], 5}));
  EXPECT_EQ(after.instruction.at(idOfSpec[4]).back(), 8u);                      // RN's default
  EXPECT_EQ(after.instruction.at(idOfSpec[7])[0], (3u << 16) | 41);              // OpConstantTrue
  EXPECT_EQ(frozen.size(), module.size() - 4 * before.specIdOf.size());
}

TEST(SpirvFreeze, RefusesWhatIsNotSpirv) {
  const std::vector<uint32_t> words = {1, 2, 3, 4, 5, 6};
  EXPECT_THROW(freezeSpecConstants(words, {}), Error);
  std::vector<uint32_t> truncated(findShader("gemm_lanes_f32").begin(), findShader("gemm_lanes_f32").begin() + 40);
  truncated.push_back(0x00FF0000u | 71);  // an instruction claiming 255 words
  EXPECT_THROW(freezeSpecConstants(truncated, {}), Error);
}

}  // namespace
}  // namespace spar::test
