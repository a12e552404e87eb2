// The model card of a packed model (model_card.h).
#include "model/model_card.h"

#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <set>

#include "spar/error.h"

namespace spar {
namespace {

std::string oneLineString(const nlohmann::json& card, const char* key, const std::string& where) {
  auto it = card.find(key);
  if (it == card.end() || !it->is_string() || it->get<std::string>().empty() ||
      it->get<std::string>().find('\n') != std::string::npos)
    throw Error(where + std::string(key) + " must be a non-empty one-line string");
  return it->get<std::string>();
}

double finiteNumber(const nlohmann::json& card, const char* key, const std::string& where) {
  auto it = card.find(key);
  if (it == card.end() || !it->is_number() || !std::isfinite(it->get<double>()))
    throw Error(where + std::string(key) + " must be a finite number");
  return it->get<double>();
}

std::string dB(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.1f dB", v);
  return b;
}

}  // namespace

ModelCard parseModelCard(const std::string& text) {
  const std::string where = "model_card: ";
  const nlohmann::json card = nlohmann::json::parse(text, nullptr, false);
  if (card.is_discarded() || !card.is_object()) throw Error(where + "not a JSON object");
  for (auto it = card.begin(); it != card.end(); ++it)
    if (!std::set<std::string>{"kind", "about", "measured", "training"}.count(it.key()))
      throw Error(where + "unknown field '" + it.key() + "' (known: kind, about, measured, training)");
  ModelCard c;
  c.kind = oneLineString(card, "kind", where);
  if (c.kind != "demonstration") throw Error(where + "unknown kind '" + c.kind + "' (known: demonstration)");
  c.about = oneLineString(card, "about", where);
  if (auto m = card.find("measured"); m != card.end()) {
    const std::string at = where + "measured.";
    if (!m->is_object() || m->size() != 4)
      throw Error(where + "measured must hold exactly what, psnr_db, baseline, baseline_psnr_db");
    c.measured = true;
    c.what = oneLineString(*m, "what", at);
    c.baseline = oneLineString(*m, "baseline", at);
    c.psnrDb = finiteNumber(*m, "psnr_db", at);
    c.baselinePsnrDb = finiteNumber(*m, "baseline_psnr_db", at);
  }
  if (auto t = card.find("training"); t != card.end()) {
    const std::string at = where + "training.";
    if (!t->is_object() || t->size() != 3)
      throw Error(where + "training must hold exactly data, steps, minutes");
    c.trained = true;
    c.trainingData = oneLineString(*t, "data", at);
    auto steps = t->find("steps");
    if (steps == t->end() || !steps->is_number_integer() || steps->get<int64_t>() < 1)
      throw Error(at + "steps must be a positive integer");
    c.trainingSteps = steps->get<int64_t>();
    c.trainingMinutes = finiteNumber(*t, "minutes", at);
    if (c.trainingMinutes <= 0) throw Error(at + "minutes must be a finite positive number");
  }
  return c;
}

std::string modelCardClaim(const ModelCard& card) {
  std::string s = "Demonstration model: " + card.about;
  if (card.measured)
    s += " (" + card.what + " PSNR " + dB(card.psnrDb) + ", " + (card.psnrDb < card.baselinePsnrDb ? "below" : "above") +
         " the " + dB(card.baselinePsnrDb) + " of " + card.baseline + ")";
  return s;
}

std::string modelCardSentence(const ModelCard& card) {
  return modelCardClaim(card) + "; " + kOfficialWeightsWhen + kOfficialWeightsAction + " (" + kOfficialWeightsDoc + ").";
}

}  // namespace spar
