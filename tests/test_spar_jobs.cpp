// Many scenes in one process, through the built `spar` on the shipped model and scenes:
// `spar render --jobs` (one device and model for every job; each job's output as a single
// `spar render` writes it), --shard for batch systems, one-line errors naming the jobs file's
// line, a failing job that does not stop the others; `spar eval --shard`.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <tuple>
#include <vector>

#include <nlohmann/json.hpp>

#include "tests/cli_test_support.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

const fs::path kData = fs::path(SPAR_SOURCE_DIR) / "samples" / "data";
const std::string kModel = (kData / "spar_rooms.spar").string();

const fs::path& scratch() { return scratchDir("spar_jobs"); }

CommandResult spar(const std::vector<std::string>& args) {
  std::vector<std::string> argv = {SPAR_CLI};
  argv.insert(argv.end(), args.begin(), args.end());
  return runValidated(argv, scratch());
}

std::string frame(const std::string& scene, int i) {
  return (kData / "scenes" / scene / ("rgb_0" + std::to_string(i) + ".png")).string();
}

// A fresh folder holding jobs.jsonl with these lines.
fs::path jobsFile(const std::string& name, const std::vector<std::string>& lines) {
  const fs::path dir = scratch() / name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  std::ofstream out(dir / "jobs.jsonl");
  for (const auto& l : lines) out << l << "\n";
  return dir / "jobs.jsonl";
}

std::string job(const std::string& out, const std::string& scene, const std::string& extra = "") {
  json j = {{"frames", {frame(scene, 0), frame(scene, 3), frame(scene, 7)}}, {"inputs", "0,2"}, {"out", out}};
  std::string s = j.dump();
  if (!extra.empty()) s.insert(s.size() - 1, "," + extra);
  return s;
}

json readJson(const fs::path& p) {
  std::ifstream in(p);
  return json::parse(in);
}

std::string bytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}

size_t lines(const std::string& s) { return size_t(std::count(s.begin(), s.end(), '\n')); }

TEST(spar_jobs, JobsShareOneDeviceAndMatchSingleRuns) {
  const fs::path file = jobsFile("two", {"# two scenes, relative outputs", job("a", "scene_1000000"),
                                         job("b", "scene_1000001", "\"path\": 3")});
  const fs::path dir = file.parent_path();
  const CommandResult r = spar({"render", "--model", kModel, "--jobs", file.string()});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.err.find("VUID"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("2 jobs done"), std::string::npos) << r.err;
  // The device was opened once: by the first job, not the second.
  const size_t opened = r.err.find("opening the Vulkan device");
  EXPECT_NE(opened, std::string::npos);
  EXPECT_EQ(r.err.find("opening the Vulkan device", opened + 1), std::string::npos) << r.err;
  for (const json& stage : readJson(dir / "b" / "report.json")["host_stages"]) {
    if (stage["name"] == "device") {
      EXPECT_LT(stage["wall_ms"].get<double>(), 1.0) << stage.dump();
    }
  }
  EXPECT_TRUE(fs::exists(dir / "b" / "path.mp4"));  // ffmpeg is installed (scripts/setup/install-deps.sh)

  // Each job writes what one `spar render` with its arguments writes.
  for (const auto& [name, scene, extra] : {std::tuple{"a", "scene_1000000", std::vector<std::string>{}},
                                           std::tuple{"b", "scene_1000001", std::vector<std::string>{"--path", "3"}}}) {
    const fs::path single = scratch() / (std::string("single_") + name);
    fs::remove_all(single);
    std::vector<std::string> args = {"render", "--model", kModel, "--frames", frame(scene, 0), frame(scene, 3),
                                     frame(scene, 7), "--inputs", "0,2", "--out", single.string()};
    args.insert(args.end(), extra.begin(), extra.end());
    const CommandResult s = spar(args);
    ASSERT_EQ(s.code, 0) << s.err;
    EXPECT_EQ(bytes(single / "view_00.png"), bytes(dir / name / "view_00.png")) << name;
    EXPECT_EQ(bytes(single / "mask_01.png"), bytes(dir / name / "mask_01.png")) << name;
  }
}

TEST(spar_jobs, ShardsSplitTheJobs) {
  const fs::path file = jobsFile("shard", {job("a", "scene_1000000"), job("b", "scene_1000001"),
                                           job("c", "scene_1000002")});
  const fs::path dir = file.parent_path();
  const CommandResult r = spar({"render", "--model", kModel, "--jobs", file.string(), "--shard", "1/2"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_FALSE(fs::exists(dir / "a"));
  EXPECT_TRUE(fs::exists(dir / "b" / "view_00.png"));
  EXPECT_FALSE(fs::exists(dir / "c"));
  for (const char* bad : {"2/2", "-1/2", "1/0", "1", "1/2x"}) {
    const CommandResult e = spar({"render", "--model", kModel, "--jobs", file.string(), "--shard", bad});
    EXPECT_EQ(e.code, 2) << bad << ": " << e.err;
    EXPECT_EQ(lines(e.err), 1u) << e.err;
    EXPECT_NE(e.err.find("--shard"), std::string::npos) << e.err;
  }
}

TEST(spar_jobs, BadJobsFileIsOneLineNamingTheLineAndWritesNothing) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"{not json", "jobs.jsonl:2: not JSON"},
      {"{\"frames\": [\"x.png\"], \"inputs\": \"0\"}", "jobs.jsonl:2: \"out\" is required"},
      {"{\"out\": \"z\", \"colour\": 1}", "jobs.jsonl:2: unknown key \"colour\""},
      {"{\"out\": \"z\", \"images\": \"a.png\"}", "jobs.jsonl:2: \"images\" must be a list"},
      {"{\"out\": \"z\", \"path\": \"ten\"}", "jobs.jsonl:2: \"path\" must be a number"},
      {"{\"out\": \"z\", \"refine\": \"yes\"}", "jobs.jsonl:2: \"refine\" must be true or false"},
      {"{\"out\": \"z\", \"mask_source\": \"soft\"}", "jobs.jsonl:2: \"mask_source\" must be \"raw\" or \"refined\""},
      {job("a", "scene_1000001"), "jobs.jsonl:2: \"out\""},  // the same out twice
  };
  for (const auto& [line, expected] : cases) {
    const fs::path file = jobsFile("bad", {job("a", "scene_1000000"), line});
    const CommandResult r = spar({"render", "--model", kModel, "--jobs", file.string()});
    EXPECT_EQ(r.code, 2) << line << ": " << r.err;
    EXPECT_EQ(lines(r.err), 1u) << r.err;
    EXPECT_NE(r.err.find(expected), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(file.parent_path() / "a")) << line;  // checked before any job ran
  }
  const fs::path empty = jobsFile("empty", {"# nothing"});
  const CommandResult r = spar({"render", "--model", kModel, "--jobs", empty.string()});
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("no jobs"), std::string::npos) << r.err;
  const CommandResult both = spar({"render", "--model", kModel, "--jobs", empty.string(), "--out", "x"});
  EXPECT_EQ(both.code, 2) << both.err;
}

TEST(spar_jobs, AFailingJobDoesNotStopTheOthers) {
  // line 4: refinement asked of a model without SAM2.1
  const fs::path file = jobsFile("failing", {job("a", "scene_1000000"),
                                             "{\"images\": [\"missing.png\", \"missing2.png\"], \"out\": \"m\"}",
                                             job("c", "scene_1000002"), job("r", "scene_1000001", "\"refine\": true")});
  const fs::path dir = file.parent_path();
  const CommandResult r = spar({"render", "--model", kModel, "--jobs", file.string()});
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_TRUE(fs::exists(dir / "a" / "view_00.png"));
  EXPECT_FALSE(fs::exists(dir / "m"));
  EXPECT_TRUE(fs::exists(dir / "c" / "view_00.png"));
  EXPECT_FALSE(fs::exists(dir / "r"));
  EXPECT_NE(r.err.find("spar: error: job at line 2: image not found"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("spar: error: job at line 4: this model has no SAM2.1 weights"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("spar: error: 2 of 4 jobs failed (lines 2, 4)"), std::string::npos) << r.err;
}

TEST(spar_jobs, EvalShardsTakeEveryNthScene) {
  const fs::path out = scratch() / "eval_shard.json";
  fs::remove(out);
  const CommandResult r = spar({"eval", "--model", kModel, "--scenes", (kData / "scenes").string(), "--views", "2",
                                "--shard", "1/2", "--out", out.string()});
  ASSERT_EQ(r.code, 0) << r.err;
  const json doc = readJson(out);
  EXPECT_EQ(doc["scenes"], 1);
  EXPECT_EQ(doc["shard"]["index"], 1);
  EXPECT_EQ(doc["shard"]["count"], 2);
  EXPECT_EQ(doc["scene_names"], json::array({"scene_1000001"}));
  const CommandResult none = spar({"eval", "--model", kModel, "--scenes", (kData / "scenes").string(), "--views",
                                   "2", "--shard", "3/4", "--max-scenes", "2", "--out", out.string()});
  EXPECT_EQ(none.code, 1) << none.err;
  EXPECT_NE(none.err.find("shard 3/4 has no scenes"), std::string::npos) << none.err;
  const CommandResult bad = spar({"eval", "--model", kModel, "--scenes", (kData / "scenes").string(), "--shard",
                                  "4/4", "--out", out.string()});
  EXPECT_EQ(bad.code, 2) << bad.err;
}

}  // namespace
}  // namespace spar::test
