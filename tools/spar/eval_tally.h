// One scene's share of `spar eval`'s metrics at one K: the sums and counts that the whole set's
// numbers are pooled from (never averages of averages). result.json keeps them per scene
// ("tallies"), so shard results merge exactly (`spar eval --merge`) and an interrupted run
// resumes per scene. The set's numbers are always the tallies added in scene order, in one
// process or from shards: both give the same doubles.
#pragma once
#include <nlohmann/json.hpp>

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "tools/spar/eval_metrics.h"

namespace spar::cli::eval {

struct SceneTally {
  int64_t targetViews = 0;           // every target view, skipped ones included
  int64_t psnrViews = 0, ssimViews = 0;  // the views with a static pixel / centre
  double psnrSum = 0, ssimSum = 0;
  double copyPsnrSum = 0, copySsimSum = 0, meanPsnrSum = 0;  // baselines on the same views
  MaskCounts masks, refinedMasks;      // CV-DRP's, SAM2.1's (--refine)
  std::optional<SemanticConfusion> semantic;
  double modelMs = 0;  // the model's work on the scene (encode, render, label maps)
  double seconds = 0;  // the scene at this K, metrics included
};

// The set at one K: the tallies pooled in the order given.
struct KTotals {
  SceneTally sum;
  std::vector<double> sceneMs;
  std::optional<double> psnr() const;
  std::optional<double> ssim() const;
  std::optional<double> copyPsnr() const;
  std::optional<double> copySsim() const;
  std::optional<double> meanPsnr() const;
};
KTotals pool(const std::vector<const SceneTally*>& tallies, int classes);

// As result.json holds a tally (doubles exact: +-inf as strings), and back. fromJson throws
// spar::Error naming `where` for a tally that is not one (or has another number of classes).
nlohmann::ordered_json toJson(const SceneTally& t);
SceneTally tallyFromJson(const nlohmann::json& j, int classes, const std::string& where);

}  // namespace spar::cli::eval
