#include "tools/spar/eval_tally.h"

#include <cmath>
#include <limits>

#include "spar/error.h"

namespace spar::cli::eval {
namespace {

using ojson = nlohmann::ordered_json;

// JSON has no infinities (a view whose static pixels match exactly has PSNR +inf): strings.
ojson number(double v) {
  if (std::isnan(v)) return "nan";
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  return v;
}

double number(const nlohmann::json& j, const char* key, const std::string& where) {
  if (!j.contains(key)) throw Error(where + ": no \"" + key + "\"");
  const nlohmann::json& v = j[key];
  if (v.is_number()) return v.get<double>();
  if (v == "inf") return std::numeric_limits<double>::infinity();
  if (v == "-inf") return -std::numeric_limits<double>::infinity();
  if (v == "nan") return std::numeric_limits<double>::quiet_NaN();
  throw Error(where + ": \"" + key + "\" is not a number");
}

int64_t count(const nlohmann::json& j, const char* key, const std::string& where) {
  if (!j.contains(key) || !j[key].is_number_integer() || j[key].get<int64_t>() < 0)
    throw Error(where + ": \"" + key + "\" is not a count");
  return j[key].get<int64_t>();
}

ojson masksJson(const MaskCounts& m) { return {{"tp", m.tp}, {"fp", m.fp}, {"fn", m.fn}, {"tn", m.tn}}; }

MaskCounts masksFromJson(const nlohmann::json& j, const char* key, const std::string& where) {
  if (!j.contains(key) || !j[key].is_object()) throw Error(where + ": no \"" + key + "\" counts");
  const std::string w = where + "." + key;
  MaskCounts m;
  m.tp = count(j[key], "tp", w), m.fp = count(j[key], "fp", w), m.fn = count(j[key], "fn", w),
  m.tn = count(j[key], "tn", w);
  return m;
}

std::vector<int64_t> counts(const nlohmann::json& j, const char* key, const std::string& where) {
  if (!j.contains(key) || !j[key].is_array()) throw Error(where + ": \"" + key + "\" is not a list of counts");
  std::vector<int64_t> out;
  for (const auto& v : j[key]) {
    if (!v.is_number_integer()) throw Error(where + ": \"" + key + "\" is not a list of counts");
    out.push_back(v.get<int64_t>());
  }
  return out;
}

std::optional<double> mean(double sum, int64_t n) { return n ? std::optional<double>(sum / double(n)) : std::nullopt; }

}  // namespace

std::optional<double> KTotals::psnr() const { return mean(sum.psnrSum, sum.psnrViews); }
std::optional<double> KTotals::ssim() const { return mean(sum.ssimSum, sum.ssimViews); }
// The baselines skip exactly the views the model's metrics skip (no static pixel / centre).
std::optional<double> KTotals::copyPsnr() const { return mean(sum.copyPsnrSum, sum.psnrViews); }
std::optional<double> KTotals::copySsim() const { return mean(sum.copySsimSum, sum.ssimViews); }
std::optional<double> KTotals::meanPsnr() const { return mean(sum.meanPsnrSum, sum.psnrViews); }

KTotals pool(const std::vector<const SceneTally*>& tallies, int classes) {
  KTotals k;
  SceneTally& s = k.sum;
  if (classes > 0) s.semantic.emplace(classes);
  for (const SceneTally* t : tallies) {
    s.targetViews += t->targetViews, s.psnrViews += t->psnrViews, s.ssimViews += t->ssimViews;
    s.psnrSum += t->psnrSum, s.ssimSum += t->ssimSum;
    s.copyPsnrSum += t->copyPsnrSum, s.copySsimSum += t->copySsimSum, s.meanPsnrSum += t->meanPsnrSum;
    s.masks.add(t->masks);
    s.refinedMasks.add(t->refinedMasks);
    if (s.semantic && t->semantic) s.semantic->add(*t->semantic);
    s.modelMs += t->modelMs, s.seconds += t->seconds;
    k.sceneMs.push_back(t->modelMs);
  }
  return k;
}

ojson toJson(const SceneTally& t) {
  ojson j = {{"target_views", t.targetViews}, {"psnr_views", t.psnrViews},   {"ssim_views", t.ssimViews},
             {"psnr_sum", number(t.psnrSum)}, {"ssim_sum", number(t.ssimSum)}, {"copy_psnr_sum", number(t.copyPsnrSum)},
             {"copy_ssim_sum", number(t.copySsimSum)}, {"mean_psnr_sum", number(t.meanPsnrSum)},
             {"masks", masksJson(t.masks)}, {"refined_masks", masksJson(t.refinedMasks)}};
  if (t.semantic)
    j["semantic"] = {{"matrix", t.semantic->matrix()},
                     {"unknown", t.semantic->unknown()},
                     {"evaluated", t.semantic->evaluated()},
                     {"correct", t.semantic->correct()}};
  j["model_ms"] = t.modelMs;
  j["seconds"] = t.seconds;
  return j;
}

SceneTally tallyFromJson(const nlohmann::json& j, int classes, const std::string& where) {
  if (!j.is_object()) throw Error(where + ": not a tally");
  SceneTally t;
  t.targetViews = count(j, "target_views", where);
  t.psnrViews = count(j, "psnr_views", where);
  t.ssimViews = count(j, "ssim_views", where);
  t.psnrSum = number(j, "psnr_sum", where);
  t.ssimSum = number(j, "ssim_sum", where);
  t.copyPsnrSum = number(j, "copy_psnr_sum", where);
  t.copySsimSum = number(j, "copy_ssim_sum", where);
  t.meanPsnrSum = number(j, "mean_psnr_sum", where);
  t.masks = masksFromJson(j, "masks", where);
  t.refinedMasks = masksFromJson(j, "refined_masks", where);
  if (classes > 0) {
    if (!j.contains("semantic") || !j["semantic"].is_object()) throw Error(where + ": no semantic counts");
    const nlohmann::json& s = j["semantic"];
    try {
      t.semantic = SemanticConfusion::fromCounts(classes, counts(s, "matrix", where), counts(s, "unknown", where),
                                                 count(s, "evaluated", where), count(s, "correct", where));
    } catch (const Error& e) {
      throw Error(where + ": " + e.what());
    }
  }
  t.modelMs = number(j, "model_ms", where);
  t.seconds = number(j, "seconds", where);
  return t;
}

}  // namespace spar::cli::eval
