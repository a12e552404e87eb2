// Many scenes in one process, through the built `spar` on the shipped model and scenes:
// `spar render --jobs` (one device and model for every job; each job's output as a single
// `spar render` writes it), --shard for batch systems, one-line errors naming the jobs file's
// line, a failing job that does not stop the others; `spar eval --shard`; reruns that finish
// only what is missing (jobs, scenes); `spar eval --merge` of shard results (docs/many-scenes.md).
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <functional>
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

const fs::path kData = fs::path(SPAR_SOURCE_DIR) / "data";
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
  // A rerun (a requeued task, a resubmitted array) renders only what is missing: b exists, so
  // its job finished; b's staging directory is what a killed run leaves.
  const std::string b = bytes(dir / "b" / "view_00.png");
  fs::create_directories(dir / "b.tmp-Ab12Cd" / "half");
  const CommandResult again = spar({"render", "--model", kModel, "--jobs", file.string(), "--shard", "1/2"});
  ASSERT_EQ(again.code, 0) << again.err;
  EXPECT_NE(again.err.find("(line 2): " + (dir / "b").string() + " exists: skipped (--redo renders it again)"),
            std::string::npos) << again.err;
  EXPECT_NE(again.err.find("(1 skipped: done by an earlier run)"), std::string::npos) << again.err;
  EXPECT_NE(again.err.find("b.tmp-Ab12Cd, left by an interrupted run"), std::string::npos) << again.err;
  EXPECT_EQ(again.err.find("opening the Vulkan device"), std::string::npos) << again.err;
  EXPECT_FALSE(fs::exists(dir / "b.tmp-Ab12Cd"));
  EXPECT_FALSE(fs::exists(dir / "a"));
  fs::remove(dir / "b" / "view_00.png");  // --redo renders the job again, whatever its folder holds
  const CommandResult redo = spar({"render", "--model", kModel, "--jobs", file.string(), "--shard", "1/2", "--redo"});
  ASSERT_EQ(redo.code, 0) << redo.err;
  EXPECT_EQ(redo.err.find("skipped"), std::string::npos) << redo.err;
  EXPECT_EQ(bytes(dir / "b" / "view_00.png"), b);
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

// The result without what differs between runs of the same evaluation: times, the shard, the
// scenes' folder (a copy here).
json withoutTimes(json doc) {
  for (auto& [k, r] : doc["results"].items()) r.erase("seconds"), r.erase("ms_per_scene");
  for (auto& [scene, byK] : doc["tallies"].items())
    for (auto& [k, t] : byK.items()) t.erase("seconds"), t.erase("model_ms");
  for (const char* key : {"shard", "merged_from", "scenes_dir"}) doc.erase(key);
  return doc;
}

void writeJsonFile(const fs::path& p, const json& doc) { std::ofstream(p) << doc.dump(1); }

fs::path evalOut(const std::string& name) {
  const fs::path out = scratch() / name;
  fs::remove(out);
  fs::remove_all(out.string() + ".partial");
  return out;
}

std::vector<std::string> evalArgs(const fs::path& scenes, const fs::path& out, std::vector<std::string> extra = {}) {
  std::vector<std::string> args = {"eval", "--model", kModel, "--scenes", scenes.string(), "--views", "2",
                                   "--max-scenes", "2", "--out", out.string()};
  args.insert(args.end(), extra.begin(), extra.end());
  return args;
}

// One test for the evaluation's reruns and shards (two scenes, K=2, so that it stays cheap):
// - an evaluation stopped midway (here: a scene whose frame cannot be read) keeps the scenes it
//   finished in OUT.partial, refuses to mix them with another evaluation's, and the same
//   command, once the scene is mended, evaluates only the others; the same command once more
//   does nothing;
// - --shard I/N takes every N-th scene, and the shards' results merge into exactly the numbers
//   of the one process (pooled sums and counts, not averages of averages);
// - results that are not parts of one evaluation are refused in one line naming the conflict.
TEST(spar_jobs, EvalResumesAndItsShardsMergeIntoOneRun) {
  const fs::path scenes = scratch() / "resume_scenes";
  fs::remove_all(scenes);
  fs::create_directories(scenes);
  for (const char* name : {"scene_1000000", "scene_1000001"})
    fs::copy(kData / "scenes" / name, scenes / name, fs::copy_options::recursive);
  const fs::path frame = scenes / "scene_1000001" / "rgb_03.png";
  std::ofstream(frame, std::ios::trunc) << "not a png";
  const fs::path out = evalOut("resume.json"), partial = scratch() / "resume.json.partial";
  const CommandResult broken = spar(evalArgs(scenes, out));
  EXPECT_EQ(broken.code, 1) << broken.err;
  EXPECT_FALSE(fs::exists(out));
  EXPECT_TRUE(fs::exists(partial / "scene_1000000.json"));
  EXPECT_FALSE(fs::exists(partial / "scene_1000001.json"));
  const CommandResult other = spar(evalArgs(scenes, out, {"--precision", "fp16"}));
  EXPECT_EQ(other.code, 1) << other.err;
  EXPECT_NE(other.err.find("holds the finished scenes of another evaluation (precision: fp32 and fp16): remove it or "
                           "pass --redo"), std::string::npos) << other.err;
  fs::copy_file(kData / "scenes" / "scene_1000001" / "rgb_03.png", frame, fs::copy_options::overwrite_existing);
  const CommandResult resumed = spar(evalArgs(scenes, out));
  ASSERT_EQ(resumed.code, 0) << resumed.err;
  EXPECT_NE(resumed.err.find("scene_1000000 was finished by an earlier run"), std::string::npos) << resumed.err;
  EXPECT_EQ(resumed.err.find("scene_1000001 was finished"), std::string::npos) << resumed.err;
  EXPECT_FALSE(fs::exists(partial));
  const json one = readJson(out);
  EXPECT_EQ(one["scene_names"], json::array({"scene_1000000", "scene_1000001"}));
  const auto written = fs::last_write_time(out);
  const CommandResult again = spar(evalArgs(scenes, out));
  ASSERT_EQ(again.code, 0) << again.err;
  EXPECT_NE(again.err.find("already holds this evaluation (2 scenes): nothing to do"), std::string::npos) << again.err;
  EXPECT_EQ(again.err.find("opening the Vulkan device"), std::string::npos) << again.err;
  EXPECT_EQ(fs::last_write_time(out), written);

  const fs::path s1 = evalOut("eval_shard1.json"), s0 = evalOut("eval_shard0.json");
  for (const auto& [path, shard] : {std::pair{s1, "1/2"}, std::pair{s0, "0/2"}}) {
    const CommandResult r = spar(evalArgs(kData / "scenes", path, {"--shard", shard}));
    ASSERT_EQ(r.code, 0) << r.err;
  }
  const json doc = readJson(s1);
  EXPECT_EQ(doc["scenes"], 1);
  EXPECT_EQ(doc["shard"]["index"], 1);
  EXPECT_EQ(doc["shard"]["count"], 2);
  EXPECT_EQ(doc["scene_names"], json::array({"scene_1000001"}));
  const fs::path merged = evalOut("eval_merged.json");
  const CommandResult m = spar({"eval", "--merge", s1.string(), s0.string(), "--out", merged.string()});
  ASSERT_EQ(m.code, 0) << m.err;
  EXPECT_NE(m.out.find("spar eval: 2 scenes"), std::string::npos) << m.out;
  const json whole = readJson(merged);
  EXPECT_EQ(whole["merged_from"].size(), 2u);
  EXPECT_EQ(withoutTimes(whole), withoutTimes(one)) << whole.dump(1) << "\n" << one.dump(1);

  auto edited = [&](const std::string& name, const fs::path& from, const std::function<void(json&)>& edit) {
    json d = readJson(from);
    edit(d);
    writeJsonFile(scratch() / name, d);
    return (scratch() / name).string();
  };
  const std::string fp16 = edited("e_fp16.json", s1, [](json& d) { d["precision"] = "fp16"; });
  const std::string model = edited("e_model.json", s1, [](json& d) { d["model_digest"] = "0123456789abcdef"; });
  const std::string views = edited("e_views.json", s1, [](json& d) { d["views"] = {3}; });
  const std::string overlap = edited("e_overlap.json", s0, [](json& d) { d["shard"]["index"] = 1; });
  const std::string third0 = edited("e_third0.json", s0, [](json& d) { d["shard"]["count"] = 3, d["set_scenes"] = 3; });
  const std::string third1 = edited("e_third1.json", s1, [](json& d) { d["shard"]["count"] = 3, d["set_scenes"] = 3; });
  for (const auto& [files, expected] : std::vector<std::pair<std::vector<std::string>, std::string>>{
           {{s0.string(), fp16}, "are not parts of one evaluation: precision: fp32 and fp16"},
           {{s0.string(), model}, "are not parts of one evaluation: model (its bytes)"},
           {{s0.string(), views}, "are not parts of one evaluation: views: [2] and [3]"},
           {{s0.string(), out.string()}, "are not parts of one evaluation: shard count: 2 and 1"},
           {{s1.string(), s1.string()}, "are both shard 1/2"},
           {{s0.string(), overlap}, "scene_1000000 is in both"},
           {{third0, third1}, "the results hold 2 of the set's 3 scenes (missing shard 2/3)"},
       }) {
    std::vector<std::string> args = {"eval", "--merge"};
    args.insert(args.end(), files.begin(), files.end());
    args.insert(args.end(), {"--out", merged.string() + ".bad"});
    const CommandResult r = spar(args);
    EXPECT_EQ(r.code, 1) << expected << ": " << r.err;
    EXPECT_EQ(lines(r.err), 1u) << r.err;
    EXPECT_NE(r.err.find(expected), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(merged.string() + ".bad"));
  }
  const CommandResult both = spar({"eval", "--merge", s0.string(), s1.string(), "--model", kModel, "--out", "x.json"});
  EXPECT_EQ(both.code, 2) << both.err;

  const CommandResult none = spar(evalArgs(kData / "scenes", evalOut("none.json"), {"--shard", "3/4"}));
  EXPECT_EQ(none.code, 1) << none.err;
  EXPECT_NE(none.err.find("shard 3/4 has no scenes"), std::string::npos) << none.err;
  const CommandResult bad = spar(evalArgs(kData / "scenes", evalOut("none.json"), {"--shard", "4/4"}));
  EXPECT_EQ(bad.code, 2) << bad.err;
}

}  // namespace
}  // namespace spar::test
