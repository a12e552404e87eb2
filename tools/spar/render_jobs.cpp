#include "tools/spar/render_jobs.h"

#include <nlohmann/json.hpp>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include "tools/common/errors.h"

namespace spar::cli {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

std::string resolve(const fs::path& base, const std::string& p) {
  return p.empty() || fs::path(p).is_absolute() ? p : (base / p).lexically_normal().string();
}

std::string text(const json& j, const char* key, const std::string& where) {
  if (!j[key].is_string()) throw UsageError(where + ": \"" + key + "\" must be a string");
  return j[key].get<std::string>();
}

std::vector<std::string> files(const json& j, const char* key, const fs::path& base, const std::string& where) {
  if (!j[key].is_array()) throw UsageError(where + ": \"" + key + "\" must be a list of image files");
  std::vector<std::string> out;
  for (const json& f : j[key]) {
    if (!f.is_string()) throw UsageError(where + ": \"" + key + "\" must be a list of image files");
    out.push_back(resolve(base, f.get<std::string>()));
  }
  return out;
}

// "0,2" or [0, 2] (integers) / "0.5,2" or [0.5, 2] (numbers) as the option's comma list.
std::string commaList(const json& j, const char* key, bool integers, const std::string& where) {
  const json& v = j[key];
  const std::string what = where + ": \"" + key + "\" must be " + (integers ? "\"0,2\" or [0, 2]" : "\"0.5,2\" or [0.5, 2]");
  if (v.is_string()) return v.get<std::string>();
  if (!v.is_array()) throw UsageError(what);
  std::string out;
  for (const json& x : v) {
    if (integers ? !x.is_number_integer() : !x.is_number()) throw UsageError(what);
    char s[32];
    if (integers) std::snprintf(s, sizeof s, "%lld", static_cast<long long>(x.get<int64_t>()));
    else std::snprintf(s, sizeof s, "%.17g", x.get<double>());
    out += (out.empty() ? "" : ",") + std::string(s);
  }
  return out;
}

RenderArgs jobArgs(const json& j, const RenderArgs& common, const fs::path& base, const std::string& where) {
  if (!j.is_object()) throw UsageError(where + ": a job is a JSON object");
  static const char* known[] = {"out",   "images", "targets",      "frames",   "inputs", "path",       "cameras",
                                "labels", "video", "video_frames", "video_at", "refine", "mask_source"};
  for (const auto& [key, value] : j.items()) {
    bool ok = false;
    std::string names;
    for (const char* k : known) {
      ok = ok || key == k;
      names += (names.empty() ? "" : ", ") + std::string(k);
    }
    if (!ok) throw UsageError(where + ": unknown key \"" + key + "\" (known: " + names + ")");
  }
  RenderArgs a = common;
  a.views = {};
  if (!j.contains("out")) throw UsageError(where + ": \"out\" is required");
  a.out = resolve(base, text(j, "out", where));
  if (j.contains("images")) a.views.images = files(j, "images", base, where);
  if (j.contains("targets")) {
    a.views.targets = files(j, "targets", base, where);
    a.views.targetsGiven = true;
  }
  if (j.contains("frames")) {
    if (j.contains("images")) throw UsageError(where + ": \"frames\" and \"images\" exclude each other");
    a.views.frames = files(j, "frames", base, where);
  }
  // A video, as --video / --video-frames / --video-at (the rest of the plan as with "frames").
  if (j.contains("video")) {
    if (j.contains("images") || j.contains("frames")) throw UsageError(where + ": \"video\" excludes \"images\" and \"frames\"");
    a.views.video = resolve(base, text(j, "video", where));
  }
  if (j.contains("video_frames")) {
    if (!j["video_frames"].is_number_integer()) throw UsageError(where + ": \"video_frames\" must be a number of frames");
    a.views.videoFrames = j["video_frames"].get<int>();
  }
  if (j.contains("video_at")) a.views.videoAt = commaList(j, "video_at", false, where);
  if (j.contains("inputs")) a.views.inputs = commaList(j, "inputs", true, where);
  if (j.contains("path")) {
    if (!j["path"].is_number_integer()) throw UsageError(where + ": \"path\" must be a number of frames");
    a.path = j["path"].get<int>();
    a.cameras.clear();
  }
  if (j.contains("cameras")) {
    a.cameras = resolve(base, text(j, "cameras", where));
    a.path.reset();
  }
  if (j.contains("labels")) a.labels = text(j, "labels", where);
  // SAM2.1 refinement per job, as --refine / --mask-source (a model packed with SAM2.1)
  if (j.contains("refine")) {
    if (!j["refine"].is_boolean()) throw UsageError(where + ": \"refine\" must be true or false");
    a.refine = j["refine"].get<bool>();
  }
  if (j.contains("mask_source")) {
    a.maskSource = text(j, "mask_source", where);
    if (a.maskSource != "raw" && a.maskSource != "refined")
      throw UsageError(where + ": \"mask_source\" must be \"raw\" or \"refined\"");
  }
  return a;
}

double secondsSince(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

// Staging directories (staged_dir.h) of `out` that a killed run left: DIR.tmp-XXXXXX. Only
// this job writes there, and this process runs it, so nothing else is using them.
void removeLeftStaging(const std::string& out) {
  const fs::path dir = fs::path(out).parent_path();
  const std::string prefix = fs::path(out).filename().string() + ".tmp-";
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.size() == prefix.size() + 6 && name.compare(0, prefix.size(), prefix) == 0) {
      std::error_code rm;
      fs::remove_all(it->path(), rm);
      if (!rm) std::fprintf(stderr, "spar: removed %s, left by an interrupted run\n", it->path().string().c_str());
    }
  }
}

}  // namespace

std::vector<RenderJob> readRenderJobs(const std::string& file, const RenderArgs& common) {
  std::ifstream in(file);
  if (!in) throw Error("cannot read jobs file " + file);
  const fs::path base = fs::absolute(file).parent_path();
  std::vector<RenderJob> jobs;
  std::string line;
  for (int n = 1; std::getline(in, line); ++n) {
    const size_t b = line.find_first_not_of(" \t\r");
    if (b == std::string::npos || line[b] == '#') continue;
    const std::string where = file + ":" + std::to_string(n);
    json j;
    try {
      j = json::parse(line);
    } catch (const json::parse_error& e) {
      std::string what = e.what();
      const size_t colon = what.rfind(": ");
      throw UsageError(where + ": not JSON (" + (colon == std::string::npos ? what : what.substr(colon + 2)) + ")");
    }
    jobs.push_back({n, jobArgs(j, common, base, where)});
  }
  if (jobs.empty()) throw UsageError(file + ": no jobs");
  std::vector<std::string> outs;
  for (const RenderJob& job : jobs) {
    for (const std::string& o : outs)
      if (o == job.args.out) throw UsageError(file + ":" + std::to_string(job.line) + ": \"out\" " + o + " is another job's too");
    outs.push_back(job.args.out);
  }
  return jobs;
}

std::pair<int, int> parseShard(const std::string& text) {
  int i = -1, n = 0;
  char rest = 0;
  if (std::sscanf(text.c_str(), "%d/%d%c", &i, &n, &rest) != 2 || n < 1 || i < 0 || i >= n)
    throw UsageError("--shard must be I/N with 0 <= I < N, e.g. 3/16, got '" + text + "'");
  return {i, n};
}

int runRenderJobs(const std::vector<RenderJob>& jobs, int shard, int shards, bool redo) {
  std::vector<const RenderJob*> mine;
  for (size_t k = 0; k < jobs.size(); ++k)
    if (int(k % size_t(shards)) == shard) mine.push_back(&jobs[k]);
  RenderContext shared;  // the device and the model, opened by the first job that gets there
  const auto start = std::chrono::steady_clock::now();
  int failed = 0, skipped = 0;
  std::string failedLines;
  for (size_t k = 0; k < mine.size(); ++k) {
    const RenderJob& job = *mine[k];
    std::error_code ec;
    removeLeftStaging(job.args.out);
    // An output directory appears only when its job finished (staged_dir.h): a rerun after a
    // kill, a time limit or a requeue renders only what is missing.
    if (!redo && fs::exists(job.args.out, ec)) {
      std::fprintf(stderr, "spar: job %zu/%zu (line %d): %s exists: skipped (--redo renders it again)\n", k + 1,
                   mine.size(), job.line, job.args.out.c_str());
      ++skipped;
      continue;
    }
    std::fprintf(stderr, "spar: job %zu/%zu (line %d): %s\n", k + 1, mine.size(), job.line, job.args.out.c_str());
    try {
      if (redo) fs::remove_all(job.args.out);
      runRender(job.args, &shared);
    } catch (const std::exception& e) {
      std::string msg = e.what();
      for (char& c : msg)
        if (c == '\n' || c == '\r') c = ' ';
      std::fprintf(stderr, "spar: error: job at line %d: %s\n", job.line, msg.c_str());
      ++failed;
      failedLines += (failedLines.empty() ? "" : ", ") + std::to_string(job.line);
    }
  }
  if (failed)
    std::fprintf(stderr, "spar: error: %d of %zu jobs failed (lines %s)\n", failed, mine.size(), failedLines.c_str());
  else if (skipped)
    std::fprintf(stderr, "spar: %zu jobs done in %.1f s (%d skipped: done by an earlier run)\n", mine.size(),
                 secondsSince(start), skipped);
  else
    std::fprintf(stderr, "spar: %zu jobs done in %.1f s\n", mine.size(), secondsSince(start));
  return failed;
}

}  // namespace spar::cli
