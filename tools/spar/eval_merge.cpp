// `spar eval --merge` (eval_command.h): shard results of one evaluation into the whole set's.
#include <nlohmann/json.hpp>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>

#include "spar/error.h"
#include "formats/cameras.h"
#include "tools/common/errors.h"
#include "tools/spar/eval_command.h"
#include "tools/spar/eval_result.h"

namespace spar::cli {

namespace fs = std::filesystem;
using namespace spar::cli::eval;

void runEvalMerge(const std::vector<std::string>& files, const std::string& out) {
  if (files.size() < 2) throw UsageError("--merge needs at least two result files");
  std::error_code ec;
  for (const std::string& f : files)
    if (fs::exists(f, ec) && fs::exists(out, ec) && fs::equivalent(f, out, ec))
      throw UsageError("--out " + out + " is one of the results merged");
  const std::string outPath = checkResultPath(out);

  EvalRun whole;
  Tallies tallies;
  std::map<std::string, std::string> from;  // scene -> the file that holds it
  std::map<int, std::string> shardFile;     // shard index -> its file
  for (size_t i = 0; i < files.size(); ++i) {
    const std::string& f = files[i];
    nlohmann::json doc;
    {
      std::ifstream in(f);
      if (!in) throw Error("cannot read " + f);
      try {
        doc = nlohmann::json::parse(in);
      } catch (const nlohmann::json::exception&) {
        throw Error(f + " is not JSON");
      }
    }
    const EvalRun run = runFromJson(doc, f);
    if (i == 0) {
      whole = run;
    } else if (const std::string diff = runDifference(whole, run); !diff.empty()) {
      throw Error(f + " and " + files[0] + " are not parts of one evaluation: " + diff);
    }
    if (auto [it, fresh] = shardFile.emplace(run.shard, f); !fresh)
      throw Error(f + " and " + it->second + " are both shard " + std::to_string(run.shard) + "/" +
                  std::to_string(run.shards));
    for (auto& [scene, byK] : talliesFromJson(doc, run, f)) {
      if (auto [it, fresh] = from.emplace(scene, f); !fresh)
        throw Error(scene + " is in both " + it->second + " and " + f + " (overlapping results)");
      tallies[scene] = std::move(byK);
    }
  }
  if (int(tallies.size()) != whole.setScenes) {
    std::string missing;
    for (int s = 0; s < whole.shards; ++s)
      if (!shardFile.count(s)) missing += (missing.empty() ? "" : ", ") + std::to_string(s) + "/" + std::to_string(whole.shards);
    throw Error("the results hold " + std::to_string(tallies.size()) + " of the set's " +
                std::to_string(whole.setScenes) + " scenes" +
                (missing.empty() ? std::string() : " (missing shard " + missing + ")"));
  }

  whole.shard = 0, whole.shards = 1;  // the whole set
  nlohmann::ordered_json doc = resultDocument(whole, tallies);
  doc["merged_from"] = nlohmann::ordered_json::array();
  for (const std::string& f : files) doc["merged_from"].push_back(absolutePath(f));
  writeResult(outPath, doc, "the shards' devices", {});
  printTable(whole, tallies, "the shards' devices");
  std::printf("wrote %s from %zu results\n", outPath.c_str(), files.size());
}

}  // namespace spar::cli
