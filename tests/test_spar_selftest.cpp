// spar selftest (tools/common/selftest_command.h): on this device it passes (exit 0, every
// op check and every stage of the self-test model within its threshold, no validation message)
// as it is and under a device-limit profile, prints the device, limits, plan and a verdict,
// gives the same as JSON and as a JUnit report (--junit), runs on every device at once
// (--all-devices, SwiftShader's found by name), and fails (exit 1, the verdict FAIL, the failing check named) when an
// op cannot run, when a stage's output is off, and when the self-test model is missing.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "formats/npy.h"
#include "tests/cli_test_support.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

const std::filesystem::path& scratch() { return scratchDir("spar_selftest"); }

// `--junit FILE`'s report: how many testcases, failures and <failure> elements it holds.
struct Junit {
  size_t testcases = 0, failureElements = 0;
  std::string text;
};
// How often `what` occurs in `text`.
size_t occurrences(const std::string& text, const std::string& what) {
  size_t n = 0;
  for (size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++n;
  return n;
}

Junit readJunit(const std::filesystem::path& file) {
  Junit j;
  j.text = readText(file);
  j.testcases = occurrences(j.text, "<testcase ");
  j.failureElements = occurrences(j.text, "<failure ");
  return j;
}

TEST(spar_selftest, PassesAndPrintsTheDeviceLimitsPlanAndVerdict) {
  const std::filesystem::path junit = scratch() / "passing.xml";
  std::filesystem::remove(junit);
  const CommandResult r = runValidated({SPAR_CLI, "selftest", "--junit", junit.string()}, scratch());
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  // the JUnit report: a testcase per check and one for the validation layer, none failed
  const Junit j = readJunit(junit);
  EXPECT_EQ(j.testcases, 38u) << j.text;
  EXPECT_EQ(j.failureElements, 0u) << j.text;
  EXPECT_NE(j.text.find("<testsuites name=\"spar selftest\" tests=\"38\" failures=\"0\""), std::string::npos) << j.text;
  EXPECT_NE(j.text.find("name=\"linear 67x130x96, q8 weights, stiff blocks\""), std::string::npos) << j.text;
  EXPECT_NE(j.text.find("name=\"validation layer messages\""), std::string::npos) << j.text;
  for (const char* part : {"device ", "limits ", "plan\n", "linear 130x768x518", "softmax 33x1001", "conv2d 3x3",
                           "validation layer: on, 0 messages", "linear 67x130x96, fp16 weights",
                           "linear 67x130x96, q8 weights, stiff blocks", "linear 67x130x96, q4 weights, stiff blocks",
                           "conv2d 3x3 pad 1, 32->13 channels at 11x9, q8 weights",
                           "conv2d 3x3 pad 1, 32->13 channels at 11x9, q4 weights",
                           "model img_tokens 1x5x16x32", "model cv_drp_input.binary", " pixels differ (",
                           "model rgb 1x2x3x64x64", "model lseg_features 1x3x16x32x32", "model text_embeddings 4x16",
                           "model label_logits 2x4x32x32", "model label_maps 2x64x64",
                           "model refined_input 3x64x64", "model refined_target 2x64x64", "model refine_iou 5x3",
                           "model refine_logits 5x64x64", "verdict: PASS (37 of 37 checks passed)"})
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
  ASSERT_EQ(doc.at("checks").size(), 12u);
  for (const auto& c : doc.at("checks")) {
    EXPECT_TRUE(c.at("passed").get<bool>()) << c.dump();
    EXPECT_LE(c.at("nmse").get<double>(), c.at("max_nmse").get<double>()) << c.dump();
    EXPECT_GT(c.at("ms").get<double>(), 0.0) << c.dump();
  }
  EXPECT_FALSE(doc.at("plan").empty());
  // The self-test model: every stage it ships a reference of, each passed (the semantic ones
  // and the labels among them, and SAM2.1's refinement of every view); the masks mixed.
  const auto& model = doc.at("model").at("checks");
  ASSERT_EQ(model.size(), 25u) << doc.at("model").dump();
  for (const auto& c : model) {
    EXPECT_TRUE(c.at("passed").get<bool>()) << c.dump();
    EXPECT_GT(c.at("ms").get<double>(), 0.0) << c.dump();
    const std::string name = c.at("name").get<std::string>();
    if (name.find(".binary") != std::string::npos || name.find("model refined_") != std::string::npos) {
      EXPECT_EQ(c.at("detail").get<std::string>().rfind("0 of ", 0), 0u) << c.dump();
      EXPECT_EQ(c.at("detail").get<std::string>().find(" 0 dynamic"), std::string::npos) << c.dump();
    } else if (name.find("label_maps") != std::string::npos) {
      EXPECT_EQ(c.at("detail").get<std::string>().rfind("0 of 8192 pixels differ", 0), 0u) << c.dump();
    } else {
      EXPECT_LE(c.at("nmse").get<double>(), c.at("max_nmse").get<double>()) << c.dump();
    }
  }
}

// A stage whose output is 1% off its reference fails that stage alone (here rgb, as a driver
// that miscomputes the renderer's last layer would, and SAM2.1's IoU predictions); a directory
// without the model is one failing line naming where it looked; a failing op fails its line
// and the verdict (the first device allocation fails: the first check cannot run; in the run
// without the model, which skips the model's stages).
// A JUnit report that cannot be written is one line before any work (no device opened).
TEST(spar_selftest, UnwritableJunitReportIsRefusedBeforeWork) {
  const std::string file = (scratch() / "no_such_dir" / "report.xml").string();
  const CommandResult r = runValidated({SPAR_CLI, "selftest", "--junit", file}, scratch());
  EXPECT_EQ(r.code, 1) << r.out << r.err;
  EXPECT_EQ(r.errLines().size(), 1u) << r.err;
  EXPECT_NE(r.err.find("spar: error: cannot write the JUnit report " + file + ": no directory"), std::string::npos) << r.err;
  EXPECT_EQ(r.out.find("device "), std::string::npos) << r.out;
}

// --all-devices: every device of this machine, SwiftShader's among them (chromium's, which
// scripts/setup/install-deps.sh installs; found without loader variables), a column each, and a
// JUnit testsuite each. Without the self-test model (the op checks only: SwiftShader's whole
// self-test is the CTest entry swiftshader.spar_selftest), so every verdict is FAIL, exit 1.
TEST(spar_selftest, AllDevicesIsOneTableWithAColumnPerDevice) {
  const std::filesystem::path junit = scratch() / "all_devices.xml";
  std::filesystem::remove(junit);
  const CommandResult r = runValidated({SPAR_CLI, "selftest", "--all-devices", "--model-dir",
                                        (scratch() / "nowhere").string(), "--junit", junit.string()}, scratch());
  EXPECT_EQ(r.code, 1) << r.out << r.err;
  EXPECT_NE(r.out.find("spar selftest --all-devices: "), std::string::npos) << r.out;
  const size_t swiftshader = r.out.find("] SwiftShader Device (Subzero), "), llvmpipe = r.out.find("] llvmpipe (");
  ASSERT_NE(swiftshader, std::string::npos) << r.out;
  ASSERT_NE(llvmpipe, std::string::npos) << r.out;
  // each op check passed on both devices, the missing model failed on both
  auto line = [&](const std::string& start) {
    const size_t at = r.out.find("\n" + start);
    return at == std::string::npos ? std::string() : r.out.substr(at + 1, r.out.find('\n', at + 1) - at - 1);
  };
  for (const char* check : {"linear 77x150x72", "softmax 33x1001", "conv2d 3x3"}) {
    const std::string row = line(check);
    EXPECT_GE(occurrences(row, "pass "), 2u) << check << "\n" << r.out;
    EXPECT_EQ(occurrences(row, "FAIL"), 0u) << check << "\n" << r.out;
  }
  EXPECT_GE(occurrences(line("model "), "FAIL (error)"), 2u) << r.out;
  EXPECT_EQ(line("validation messages").find_first_not_of("validation messages 0"), std::string::npos) << r.out;
  EXPECT_GE(occurrences(line("verdict"), "FAIL "), 2u) << r.out;
  const Junit j = readJunit(junit);
  EXPECT_GE(occurrences(j.text, "<testsuite name=\"spar selftest on "), 2u) << j.text;
  EXPECT_NE(j.text.find("<testsuite name=\"spar selftest on SwiftShader Device (Subzero), "), std::string::npos) << j.text;
  EXPECT_NE(j.text.find("<testsuite name=\"spar selftest on llvmpipe ("), std::string::npos) << j.text;
}

// SwiftShader joins only when named (`--device swiftshader`: the CTest entry
// swiftshader.spar_selftest): the device list another name sees is the loader's own (lavapipe
// here), and so is the default choice; drivers the user chose (VK_ICD_FILENAMES) stay the only ones.
TEST(spar_selftest, SwiftShaderJoinsOnlyWhenNamed) {
  CommandResult r = runValidated({SPAR_CLI, "selftest", "--device", "no-such-gpu"}, scratch());
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("no Vulkan device matches 'no-such-gpu' (available: 0: llvmpipe"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("SwiftShader"), std::string::npos) << r.err;
  r = runValidated({SPAR_CLI, "selftest", "--device", "swiftshader"}, scratch(),
                   "VK_ICD_FILENAMES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("no Vulkan device matches 'swiftshader' (available: 0: llvmpipe"), std::string::npos) << r.err;
}

TEST(spar_selftest, AStageOffItsReferenceAMissingModelOrAFailingOpFailsTheVerdict) {
  const std::filesystem::path model = scratch() / "off_model";
  std::filesystem::remove_all(model);
  std::filesystem::copy(SPAR_SELFTEST_SOURCE_DATA, model, std::filesystem::copy_options::recursive);
  for (const char* stage : {"rgb", "refine_iou"}) {
    const std::string file = (model / "reference" / (std::string(stage) + ".npy")).string();
    NpyArray golden = readNpy(file);
    std::vector<double> v = golden.toDoubles();
    for (double& x : v) x *= 1.01;
    writeNpy(file, golden.shape, v.data());
  }
  const std::filesystem::path junit = scratch() / "failing.xml";
  std::filesystem::remove(junit);
  CommandResult r = runValidated({SPAR_CLI, "selftest", "--model-dir", model.string(), "--junit", junit.string()}, scratch());
  EXPECT_EQ(r.code, 1) << r.out << r.err;
  // the two failing stages are failures in the JUnit report too, with what was measured
  const Junit j = readJunit(junit);
  EXPECT_EQ(j.testcases, 38u) << j.text;
  EXPECT_EQ(j.failureElements, 2u) << j.text;
  EXPECT_NE(j.text.find("tests=\"38\" failures=\"2\""), std::string::npos) << j.text;
  EXPECT_NE(j.text.find("<failure message=\"family "), std::string::npos) << j.text;
  EXPECT_NE(r.out.find("FAIL  model rgb 1x2x3x64x64"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("FAIL  model refine_iou 5x3"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("pass  model decoder_out"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("pass  model refine_logits"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("verdict: FAIL (35 of 37 checks passed)"), std::string::npos) << r.out;

  r = runValidated({SPAR_CLI, "selftest", "--model-dir", (scratch() / "nowhere").string()}, scratch(),
                   "SPAR_FAULT_ALLOCATION=1");
  EXPECT_EQ(r.code, 1) << r.out << r.err;
  EXPECT_NE(r.out.find("FAIL  linear 77x150x72"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("pass  linear 130x768x518"), std::string::npos) << r.out;  // the next check runs
  EXPECT_NE(r.out.find("FAIL  model"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("the self-test model is not in " + (scratch() / "nowhere").string()), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("verdict: FAIL (11 of 13 checks passed)"), std::string::npos) << r.out;
}

}  // namespace
}  // namespace spar::test
