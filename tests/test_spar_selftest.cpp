// spar selftest (samples/spar_cli/selftest_command.h): on this device it passes (exit 0, every
// check within its threshold, no validation message) as it is and under the tightest
// device-limit profile, prints the device, limits, plan and a verdict, gives the same as JSON,
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

TEST(spar_selftest, JsonUnderTheVulkanMinimumProfile) {
  const CommandResult r = runValidated({SPAR_CLI, "selftest", "--json"}, scratch(), "SPAR_DEVICE_LIMITS=vulkan-1.2-min");
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  const auto doc = nlohmann::json::parse(r.out);
  EXPECT_TRUE(doc.at("passed").get<bool>());
  EXPECT_NE(doc.at("profile").get<std::string>().find("vulkan-1.2-min"), std::string::npos);
  EXPECT_EQ(doc.at("limits").at("max_texel_buffer_elements").get<uint64_t>(), 65536u);
  EXPECT_EQ(doc.at("validation").at("messages").get<int>(), 0);
  ASSERT_EQ(doc.at("checks").size(), 7u);  // no fp16 weights under this profile
  for (const auto& c : doc.at("checks")) {
    EXPECT_TRUE(c.at("passed").get<bool>()) << c.dump();
    EXPECT_LE(c.at("nmse").get<double>(), c.at("max_nmse").get<double>()) << c.dump();
    EXPECT_GT(c.at("ms").get<double>(), 0.0) << c.dump();
  }
  bool storageInputs = false;
  for (const auto& line : doc.at("plan")) storageInputs |= line.get<std::string>().find("storage buffers") != std::string::npos;
  EXPECT_TRUE(storageInputs) << doc.at("plan").dump();
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
