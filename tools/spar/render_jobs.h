// `spar render --jobs FILE`: many renders in one process, sharing one device (kernels compiled
// once) and one opened model. FILE holds one job a line, JSON (JSON Lines), each naming what
// differs between scenes; everything else comes from the command line (model, precision,
// --size, --assume-static, --labels, --features, ...):
//
//   {"frames": ["s1/rgb_00.png", "s1/rgb_01.png", "s1/rgb_02.png"], "inputs": "0,2", "out": "out/s1"}
//   {"images": ["a.png", "b.png"], "targets": ["c.png"], "out": "out/s2", "path": 24}
//
// Keys: "out" (required), "images" / "targets" or "frames" + "inputs" (as the options of the
// same names), and optionally "path", "cameras", "labels" (overriding the command line's).
// Relative paths are relative to FILE's folder. Empty lines and lines starting with # are
// skipped. --shard I/N runs the jobs whose position (0-based, counting jobs only) is I modulo N:
// one process per shard under a batch system (Slurm job arrays, ...), one --device each.
#pragma once
#include <string>
#include <vector>

#include "tools/spar/render_command.h"

namespace spar::cli {

struct RenderJob {
  int line = 0;  // 1-based line of FILE
  RenderArgs args;
};

// Parses FILE; `common` is the command line's arguments. Throws UsageError naming the line for
// a job that cannot mean anything, spar::Error for a file that cannot be read.
std::vector<RenderJob> readRenderJobs(const std::string& file, const RenderArgs& common);

// --shard "I/N" -> (I, N) with 0 <= I < N; throws UsageError otherwise.
std::pair<int, int> parseShard(const std::string& text);

// Runs the jobs of the shard in order, each as `spar render` would run it (its own output
// directory, written whole); a failing job prints its one-line error and the next one runs.
// A job whose output directory exists was finished by an earlier run and is skipped (its line
// on stderr says so), unless `redo`; staging directories a killed run left are removed.
// Returns the number of jobs that failed; progress on stderr, a summary line at the end.
int runRenderJobs(const std::vector<RenderJob>& jobs, int shard, int shards, bool redo = false);

}  // namespace spar::cli
