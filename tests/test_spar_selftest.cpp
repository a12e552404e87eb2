// spar selftest (samples/spar_cli/selftest_command.h): on this device it passes (exit 0, every
// check within its threshold, no validation message) as it is and under a device-limit
// profile, prints the device, limits, plan and a verdict, gives the same as JSON,
// and fails (exit 1, the verdict FAIL, the failing check named) when an op cannot run.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "tests/cli_test_support.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

const std::filesystem::path& scratch() { return scratchDir("spar_selftest"); }

TEST(spar_selftest, PassesAndPrintsTheDeviceLimitsPlanAndVerdict) {
  const CommandResult r = runValidated({SPAR_CLI, "selftest"}, scratch());
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  for (const char* part : {"device ", "limits ", "plan\n", "linear 130x768x518", "softmax 33x1001", "conv2d 3x3",
                           "validation layer: on, 0 messages", "linear 67x130x96, fp16 weights", "verdict: PASS (8 of 8 checks passed)"})
    EXPECT_NE(r.out.find(part), std::string::npos) << part << "\n" << r.out;
}

// Under a profile whose kernels are the ones the first test compiled (the storage-input kernels
// of vulkan-1.2-min compile for 25 s on a cold cache: `spar selftest` under every profile runs
// with -C profiles, tests/CMakeLists.txt).
TEST(spar_selftest, JsonUnderARaspberryPiProfile) {
  const CommandResult r = runValidated({SPAR_CLI, "selftest", "--json"}, scratch(), "SPAR_DEVICE_LIMITS=raspberry-pi-5");
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  const auto doc = nlohmann::json::parse(r.out);
  EXPECT_TRUE(doc.at("passed").get<bool>());
  EXPECT_NE(doc.at("profile").get<std::string>().find("raspberry-pi-5"), std::string::npos);
  EXPECT_LE(doc.at("limits").at("max_compute_workgroup_invocations").get<uint32_t>(), 256u);
  EXPECT_LE(doc.at("limits").at("max_compute_shared_memory_size").get<uint32_t>(), 16384u);
  EXPECT_FALSE(doc.at("limits").at("shader_float16").get<bool>());
  EXPECT_EQ(doc.at("validation").at("messages").get<int>(), 0);
  ASSERT_EQ(doc.at("checks").size(), 8u);
  for (const auto& c : doc.at("checks")) {
    EXPECT_TRUE(c.at("passed").get<bool>()) << c.dump();
    EXPECT_LE(c.at("nmse").get<double>(), c.at("max_nmse").get<double>()) << c.dump();
    EXPECT_GT(c.at("ms").get<double>(), 0.0) << c.dump();
  }
  EXPECT_FALSE(doc.at("plan").empty());
}

TEST(spar_selftest, AFailingOpFailsTheVerdict) {
  // The first device allocation fails: the first check cannot run.
  const CommandResult r = runValidated({SPAR_CLI, "selftest"}, scratch(), "SPAR_FAULT_ALLOCATION=1");
  EXPECT_EQ(r.code, 1) << r.out << r.err;
  EXPECT_NE(r.out.find("FAIL  linear 77x150x72"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("verdict: FAIL (7 of 8 checks passed)"), std::string::npos) << r.out;
}

}  // namespace
}  // namespace spar::test
