// Faults injected into the engine (EngineOptions::faults, through SPAR_FAULT_ALLOCATION /
// SPAR_FAULT_SUBMISSION) while the built `spar` (SPAR_CLI) renders the tiny photometric fixture:
// whichever device buffer allocation fails as out of memory, or whichever submission's wait
// times out, the run ends with exit 1, one error line that says what failed (how much memory,
// which stage), no output directory and no temporary one, and no Vulkan object left alive
// (the validation layer reports those at vkDestroyDevice; runValidated fails on any message).
// The failure points are spread over the whole run: the run's own count of allocations and
// submissions (report.json device_memory) is taken first, and a fault beyond it changes nothing.
// A memory limit (SPAR_MEMORY_LIMIT_MB) below the request's estimated need refuses it before any
// work; one between the estimate and the measured peak fails it midway, also as one line.
// The suite is named "spar_faults" (`ctest -R spar_faults`).
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "tests/golden_support.h"
#include "tests/cli_test_support.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;

const fs::path& scratch() { return scratchDir("spar_faults"); }
const fs::path& out() {
  static const fs::path o = scratch() / "out";
  return o;
}

CommandResult render(const std::string& env) {
  fs::remove_all(out());
  std::vector<std::string> argv = {SPAR_CLI, "render", "--model", goldenPath("tiny.spar"), "--images"};
  for (int i : {0, 2, 4}) argv.push_back(goldenPath("frame_" + std::to_string(i) + ".png"));
  for (const char* a : {"--targets"}) argv.push_back(a);
  argv.push_back(goldenPath("frame_1.png"));
  argv.push_back("--path");  // the path renders in its own submissions after the targets'
  argv.push_back("3");
  argv.push_back("--out");
  argv.push_back(out().string());
  return runValidated(argv, scratch(), env);
}

// The run's counts without faults.
nlohmann::json counts() {
  static const nlohmann::json c = [] {
    const CommandResult r = render("");
    EXPECT_EQ(r.code, 0) << r.err;
    std::ifstream in(out() / "report.json");
    return nlohmann::json::parse(in)["device_memory"];
  }();
  return c;
}

// 1, 2, 3, 5, 8, ... up to n, and n itself: early, middle and last failure points.
std::vector<unsigned long long> spread(unsigned long long n) {
  std::set<unsigned long long> s{n};
  for (unsigned long long a = 1, b = 2; a < n; std::swap(a, b), b += a) s.insert(a);
  return {s.begin(), s.end()};
}

void expectCleanFailure(const CommandResult& r, const std::string& says, const std::string& what) {
  EXPECT_EQ(r.code, 1) << what << ": " << r.err;
  const std::vector<std::string> lines = r.errLines();
  ASSERT_FALSE(lines.empty()) << what;
  // progress lines, then exactly one error line, the last
  size_t errors = 0;
  for (const auto& l : lines) errors += l.rfind("spar: error: ", 0) == 0;
  EXPECT_EQ(errors, 1u) << what << ": " << r.err;
  EXPECT_EQ(lines.back().rfind("spar: error: ", 0), 0u) << what << ": " << r.err;
  EXPECT_NE(lines.back().find(says), std::string::npos) << what << ": " << lines.back();
  EXPECT_FALSE(fs::exists(out())) << what;
  for (const auto& e : fs::directory_iterator(scratch()))
    EXPECT_EQ(e.path().filename().string().rfind("out.tmp", 0), std::string::npos) << what << ": " << e.path();
}

// A fault of one kind injected at points spread over the run's own count of them (report.json
// device_memory[countKey]), each a clean failure that says `says`; one past the count is no fault.
void expectEveryFaultClean(const char* countKey, const std::string& variable, const std::string& injected,
                           const std::string& says) {
  const unsigned long long n = counts()[countKey].get<unsigned long long>();
  ASSERT_GT(n, 5u) << countKey;
  for (unsigned long long i : spread(n)) {
    const CommandResult r = render(variable + "=" + std::to_string(i));
    expectCleanFailure(r, says, injected + " " + std::to_string(i));
    EXPECT_NE(r.err.find("(injected: " + injected + " " + std::to_string(i) + ")"), std::string::npos) << r.err;
  }
  std::printf("%llu %s in the run; faults injected at %zu of them\n", n, countKey, spread(n).size());
  EXPECT_EQ(render(variable + "=" + std::to_string(n + 1)).code, 0);
}

TEST(spar_faults, EveryAllocationFailureIsOneLineNoOutputNoLeak) {
  expectEveryFaultClean("allocations", "SPAR_FAULT_ALLOCATION", "allocation", "of device memory with");
}

TEST(spar_faults, EverySubmissionTimeoutIsOneLineNoOutputNoLeak) {
  expectEveryFaultClean("submissions", "SPAR_FAULT_SUBMISSION", "submission", "the device did not finish a ");
}

// model/memory_estimate.h: its two bounds bracket what the run used, neither a loose one.
TEST(spar_faults, MemoryEstimatesBracketThePeak) {
  counts();
  std::ifstream in(out() / "report.json");
  expectMemoryBounds(nlohmann::json::parse(in), "targets and a path, tiny model");
  EXPECT_GT(counts()["max_input_views"].get<int64_t>(), 3);
}

// The same where convolutions run as im2col and the lanes GEMM (SwiftShader's plan, forced
// here: engine/ops/conv2d.cpp): the recorders' patch scratch is in the upper bound.
TEST(spar_faults, MemoryEstimatesBracketThePeakWithIm2colConvolutions) {
  const CommandResult r = render("SPAR_KERNELS=cpu SPAR_GEMM_LANES=1");
  ASSERT_EQ(r.code, 0) << r.err;
  std::ifstream in(out() / "report.json");
  const auto report = nlohmann::json::parse(in);
  bool im2col = false;
  for (const auto& k : report["kernels"]["list"]) im2col = im2col || k["name"].get<std::string>().rfind("im2col", 0) == 0;
  EXPECT_TRUE(im2col);
  expectMemoryBounds(report, "targets and a path, tiny model, im2col convolutions");
}

// Less memory than the estimate: refused before any work, saying how much it needs.
TEST(spar_faults, RequestLargerThanTheDeviceIsRefusedBeforeWork) {
  const uint64_t needMiB = counts()["estimated_min_bytes"].get<uint64_t>() >> 20;
  ASSERT_GT(needMiB, 1u);
  const CommandResult r = render("SPAR_MEMORY_LIMIT_MB=" + std::to_string(needMiB - 1));
  expectCleanFailure(r, "this request needs at least " + std::to_string(needMiB + 1) + " MiB of device memory",
                     "memory limit below the estimate");
  EXPECT_EQ(r.err.find("spar: encoding"), std::string::npos) << r.err;  // no work began
  // The same with a device-limit profile whose memory is below the need: the error names it.
  const fs::path profile = scratch() / "small_board.json";
  std::ofstream(profile) << "{\"name\": \"small-board\", \"deviceMemoryBytes\": " << ((needMiB - 1) << 20) << "}";
  const CommandResult p = render("SPAR_DEVICE_LIMITS=" + profile.string());
  expectCleanFailure(p, "(the memory of device-limit profile small-board)", "profile memory below the estimate");
  EXPECT_EQ(p.err.find("spar: encoding"), std::string::npos) << p.err;
}

// Between the estimate and the peak: it runs out during the work, as on a smaller device, and
// says so in one line, with nothing written and nothing leaked.
TEST(spar_faults, RunningOutOfMemoryMidwayIsOneLine) {
  const uint64_t between = (counts()["estimated_min_bytes"].get<uint64_t>() + counts()["peak_bytes"].get<uint64_t>()) / 2;
  const CommandResult r = render("SPAR_MEMORY_LIMIT_MB=" + std::to_string((between >> 20) + 1));
  expectCleanFailure(r, "over the memory limit of", "memory limit between estimate and peak");
  // the upper bound was above the limit, and the run said before work that it might not fit
  EXPECT_NE(r.err.find("spar: warning: this request may need up to"), std::string::npos) << r.err;
}

TEST(spar_faults, MalformedFaultSettingIsOneLine) {
  const CommandResult r = render("SPAR_FAULT_ALLOCATION=-3");
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_NE(r.err.find("SPAR_FAULT_ALLOCATION must be a non-negative integer"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace spar::test
