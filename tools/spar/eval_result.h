// result.json of `spar eval` (evaluation/PROTOCOL.md, "Output JSON"): what was evaluated (the
// run), the per-scene tallies, and the set's metrics pooled from them; written by an
// evaluation and by a merge of shard results, read back by both (a merge, a resumed run).
#pragma once
#include <nlohmann/json.hpp>

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "tools/spar/eval_tally.h"

namespace spar::cli::eval {

// What two results must share to be parts of one evaluation, and what they must share to
// merge: the model's bytes, the settings, the scenes' frames, size and classes, the set.
struct EvalRun {
  std::string model;        // the path given (informative: nodes may mount it elsewhere)
  std::string scenesDir;    // likewise; a rerun into the same result compares it
  std::string modelDigest;  // modelDigest() of the file's bytes
  uint64_t modelBytes = 0;
  std::string precision, mode;
  bool refine = false, semantic = false;
  int frames = 0, height = 0, width = 0;
  std::vector<int> views;
  std::vector<std::string> classNames;
  int setScenes = 0;        // scenes of the whole test set (after --max-scenes)
  int shard = 0, shards = 1;
  bool masks() const { return mode != "assume-static"; }
};

// scene name -> K -> its tally; std::map's bytewise order is the test set's scene order.
using Tallies = std::map<std::string, std::map<int, SceneTally>>;

// A 64-bit digest of a file's bytes, as 16 hex digits (not cryptographic: it tells models
// apart, it does not authenticate them). Throws spar::Error when the file cannot be read.
std::string modelDigest(const std::string& path);

// The keys of a result that describe its run, and back (throws spar::Error naming `where`).
nlohmann::ordered_json runJson(const EvalRun& run);
EvalRun runFromJson(const nlohmann::json& doc, const std::string& where);
// "" when a and b are parts of one evaluation, else what differs ("precision: fp16 and fp32");
// the shard index is not compared.
std::string runDifference(const EvalRun& a, const EvalRun& b);

// The whole result.json: the run, the set's metrics per K pooled from the tallies in scene
// order, the scene names and their tallies.
nlohmann::ordered_json resultDocument(const EvalRun& run, const Tallies& tallies);
// The tallies of a result (throws spar::Error naming `where` when a scene or K is missing).
Tallies talliesFromJson(const nlohmann::json& doc, const EvalRun& run, const std::string& where);

// --out of an evaluation or a merge, checked before any work: its folder exists and takes a
// file, it is not a folder. Returns it absolute; throws spar::Error.
std::string checkResultPath(const std::string& out);
// result.json (written whole) and the same as a page beside it (result.html).
void writeResult(const std::string& path, const nlohmann::ordered_json& doc, const std::string& device,
                 const std::vector<std::string>& warnings);

// The table `spar eval` prints on stdout.
void printTable(const EvalRun& run, const Tallies& tallies, const std::string& device);

}  // namespace spar::cli::eval
