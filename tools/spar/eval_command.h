// `spar eval`: the evaluation protocol of evaluation/PROTOCOL.md on the engine.
// For each K of --views and each scene of --scenes (DIR/scene_* sorted bytewise): one SPAR run
// on all F frames in order with the protocol's K inputs, the other frames as targets rendered
// with their estimated cameras; static-pixel PSNR / SSIM of the rendered targets (floats, not
// 8-bit), motion-mask counts over all F frames, semantic confusion of the targets' label maps
// (semantic models; the scene's class names as prompts); with --refine the SAM2.1-refined masks'
// counts too, beside CV-DRP's. Writes result.json (written whole:
// temporary name, then rename) and prints a table on stdout; progress on stderr.
// result.json keeps each scene's sums and counts (eval_tally.h): `--merge` pools shard results
// exactly, and a rerun of the same command finishes only what is missing (the scenes an
// interrupted run finished wait in <out>.partial; a complete result of the same run is kept).
#pragma once
#include <cstdint>
#include <string>
#include <vector>

namespace spar::cli {

struct EvalArgs {
  std::string model;
  std::string scenes;              // directory of scene_* folders
  std::string views = "2,3,4";     // K values, comma-separated
  std::string precision = "fp32";  // fp32 | fp16
  int64_t height = 0, width = 0;   // --size HxW; 0: the model's image size (its training size)
  bool noGating = false;           // CV-DRP runs, no token is gated
  bool assumeStatic = false;       // no DINOv3 / CV-DRP, no gating, no mask metrics
  bool refine = false;             // SAM2.1-refined masks scored beside CV-DRP's
  std::string maskSource = "raw";  // raw | refined: the masks that gate the input tokens
  int maxScenes = 0;               // 0: all
  int shard = 0, shards = 1;       // --shard I/N: every N-th scene from the I-th
  std::string device;
  std::string out;                 // result.json
  bool redo = false;               // evaluate every scene again, whatever an earlier run left
};

// Throws UsageError (exit 2) or spar::Error (exit 1).
void runEval(const EvalArgs& args);

// `spar eval --merge R1.json R2.json ... --out ALL.json`: one result for the whole test set
// from shard results, pooled from their per-scene tallies in scene order (the numbers one
// process over every scene gives). Results of different runs (model bytes, precision, mode,
// views, size, classes, set, shard count), overlapping scenes or missing shards are refused
// in one line naming the files and the conflict (spar::Error).
void runEvalMerge(const std::vector<std::string>& results, const std::string& out);

}  // namespace spar::cli
