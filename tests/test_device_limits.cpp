// Device-limit profiles (include/spar/device_limits.h, engine/device_limits.cpp): the named
// profiles, the JSON form and its errors, that a profile only tightens what the device has and
// turns features off (never on), that the kernel plan follows (storage-buffer inputs where texel
// buffers are short), and that the profile's memory is the memory budget, named in errors.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "engine/engine.h"
#include "spar/error.h"
#include "test_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;

fs::path writeJson(const std::string& name, const std::string& text) {
  const fs::path p = scratchDir("device_limits") / name;
  std::ofstream(p) << text;
  return p;
}

Engine engineWith(const DeviceLimits& limits) {
  EngineOptions o;
  o.validation = true;
  o.limits = limits;
  return Engine(o);
}

TEST(DeviceLimits, NamedProfilesAreTheDocumentedOnes) {
  EXPECT_EQ(DeviceLimits::profileNames(),
            (std::vector<std::string>{"vulkan-1.2-min", "android-baseline-2022", "raspberry-pi-5", "mali-g610", "adreno-610"}));
  const DeviceLimits min = DeviceLimits::profile("vulkan-1.2-min");
  EXPECT_EQ(min.maxTexelBufferElements, 65536u);
  EXPECT_EQ(min.maxStorageBufferRange, uint64_t(1) << 27);
  EXPECT_EQ(min.maxComputeSharedMemorySize, 16384u);
  EXPECT_EQ(min.maxComputeWorkGroupInvocations, 128u);
  EXPECT_EQ(min.maxPerStageDescriptorStorageBuffers, 4u);
  EXPECT_EQ(min.shaderFloat16, false);
  EXPECT_NE(min.describe().find("texel-buffer elements 65536"), std::string::npos) << min.describe();
  for (const std::string& name : DeviceLimits::profileNames()) EXPECT_EQ(DeviceLimits::parse(name).name, name);
  try {
    DeviceLimits::parse("iphone");
    FAIL() << "an unknown profile name was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("known: vulkan-1.2-min, android-baseline-2022"), std::string::npos) << e.what();
  }
}

TEST(DeviceLimits, JsonFileAndItsErrorsAreOneLine) {
  const fs::path good = writeJson("board.json", R"({"name": "board", "maxComputeWorkGroupInvocations": 64,
      "shaderFloat16": false, "deviceMemoryBytes": 1048576})");
  const DeviceLimits l = DeviceLimits::parse(good.string());
  EXPECT_EQ(l.name, "board");
  EXPECT_EQ(l.maxComputeWorkGroupInvocations, 64u);
  EXPECT_EQ(l.shaderFloat16, false);
  EXPECT_EQ(l.deviceMemoryBytes, 1048576u);
  EXPECT_FALSE(l.maxTexelBufferElements.has_value());
  const std::vector<std::pair<std::string, std::string>> bad = {
      {R"({"maxTexelBufferEntries": 5})", "unknown field 'maxTexelBufferEntries'"},
      {R"({"maxTexelBufferElements": -5})", "maxTexelBufferElements must be a positive integer"},
      {R"({"maxTexelBufferElements": 0})", "maxTexelBufferElements must be a positive integer"},
      {R"({"maxComputeWorkGroupInvocations": 5000000000})", "must be a positive integer"},
      {R"({"shaderFloat16": 1})", "shaderFloat16 must be true or false"},
      {R"({"minStorageBufferOffsetAlignment": 48})", "powers of two"},
      {R"([1, 2])", "must hold a JSON object"},
      {R"({"name": )", "is not JSON"},
  };
  for (size_t i = 0; i < bad.size(); ++i) {
    const fs::path p = writeJson("bad" + std::to_string(i) + ".json", bad[i].first);
    try {
      DeviceLimits::parse(p.string());
      ADD_FAILURE() << bad[i].first << " was accepted";
    } catch (const Error& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find(bad[i].second), std::string::npos) << what;
      EXPECT_NE(what.find(p.string()), std::string::npos) << what;
      EXPECT_EQ(what.find('\n'), std::string::npos) << what;
    }
  }
  EXPECT_THROW(DeviceLimits::parse("/nonexistent/limits.json"), Error);
}

TEST(DeviceLimits, FromTheEnvironment) {
  ScopedEnv env("SPAR_DEVICE_LIMITS", "raspberry-pi-5");
  EXPECT_EQ(EngineOptions::fromEnvironment().limits.name, "raspberry-pi-5");
  ScopedEnv bad("SPAR_DEVICE_LIMITS", "raspberry-pi-6");
  EXPECT_THROW(EngineOptions::fromEnvironment(), Error);
}

TEST(DeviceLimits, ProfileTightensTheDeviceAndThePlanFollows) {
  Engine plain = engineWith({});
  const DeviceCaps real = plain.caps();
  Engine e = engineWith(DeviceLimits::profile("vulkan-1.2-min"));
  const DeviceCaps& c = e.caps();
  EXPECT_EQ(c.limitsProfile, "vulkan-1.2-min");
  EXPECT_EQ(c.maxTexelBufferElements, std::min<uint64_t>(real.maxTexelBufferElements, 65536));
  EXPECT_EQ(c.maxWorkGroupInvocations, std::min<uint32_t>(real.maxWorkGroupInvocations, 128));
  EXPECT_EQ(c.maxSharedMemory, std::min<uint32_t>(real.maxSharedMemory, 16384));
  EXPECT_EQ(c.maxPerStageStorageBuffers, std::min<uint32_t>(real.maxPerStageStorageBuffers, 4));
  EXPECT_EQ(c.minStorageBufferOffsetAlignment, std::max<uint64_t>(real.minStorageBufferOffsetAlignment, 256));
  EXPECT_FALSE(c.shaderFloat16);
  EXPECT_FALSE(c.supportsFp16Storage());
  EXPECT_FALSE(c.subgroupArithmetic);
  EXPECT_FALSE(c.cooperativeMatrix);
  EXPECT_EQ(e.device().bindingRangeLimit(), c.maxStorageBufferRange);
  EXPECT_TRUE(e.plan().storageInputs);
  EXPECT_EQ(plain.plan().storageInputs, real.maxTexelBufferElements * 4 < real.maxStorageBufferRange);
  // A profile cannot loosen: values above the device's stay the device's, a feature set true
  // stays as the device has it.
  DeviceLimits loose;
  loose.name = "loose";
  loose.maxTexelBufferElements = real.maxTexelBufferElements * 2;
  loose.maxComputeWorkGroupInvocations = real.maxWorkGroupInvocations * 2;
  loose.minStorageBufferOffsetAlignment = 1;
  loose.cooperativeMatrix = true;
  Engine l = engineWith(loose);
  EXPECT_EQ(l.caps().maxTexelBufferElements, real.maxTexelBufferElements);
  EXPECT_EQ(l.caps().maxWorkGroupInvocations, real.maxWorkGroupInvocations);
  EXPECT_EQ(l.caps().minStorageBufferOffsetAlignment, real.minStorageBufferOffsetAlignment);
  EXPECT_EQ(l.caps().cooperativeMatrix, real.cooperativeMatrix);
  // A kernel with more bindings than the profile allows is refused naming the limit.
  try {
    e.kernel({"binary_add", {Bind::Read, Bind::Read, Bind::Read, Bind::Read, Bind::Write}, 0, {64, 1, 1}});
    FAIL() << "five storage buffers were accepted under vulkan-1.2-min";
  } catch (const Error& err) {
    EXPECT_NE(std::string(err.what()).find("the device allows 4"), std::string::npos) << err.what();
  }
  EXPECT_EQ(e.device().validationMessageCount(), 0u);
}

TEST(DeviceLimits, ProfileMemoryIsTheBudgetAndNamedInErrors) {
  DeviceLimits small;
  small.name = "one-mebibyte";
  small.deviceMemoryBytes = 1 << 20;
  Engine e = engineWith(small);
  EXPECT_EQ(e.memory().budget(), 1u << 20);
  EXPECT_NE(e.memory().budgetSource().find("device-limit profile one-mebibyte"), std::string::npos);
  Tensor fits = e.tensor({1024});
  try {
    Tensor tooBig = e.tensor({1 << 20});
    FAIL() << "4 MiB allocated under a 1 MiB profile";
  } catch (const Error& err) {
    EXPECT_NE(std::string(err.what()).find("device-limit profile one-mebibyte"), std::string::npos) << err.what();
  }
  // The smaller of the option's limit and the profile's wins.
  EngineOptions o;
  o.limits = small;
  o.memoryLimitBytes = 512 << 10;
  Engine both(o);
  EXPECT_EQ(both.memory().budget(), 512u << 10);
  EXPECT_NE(both.memory().budgetSource().find("SPAR_MEMORY_LIMIT_MB"), std::string::npos);
}

}  // namespace
}  // namespace spar::test
