// The self-test model (selftest_model.h).
#include "selftest/selftest_model.h"

#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>

#include "spar/error.h"
#include "formats/npy.h"
#include "model/packed_model.h"
#include "model/prompt_label_maps.h"
#include "model/spar_pipeline.h"
#include "model/stage_tolerances.h"

namespace spar::selftest {
namespace fs = std::filesystem;
namespace {

constexpr double kUnbounded = std::numeric_limits<double>::infinity();

// The pipeline stage (SparPipeline's stage names, model/spar_pipeline.cpp) that makes each
// output the self-test compares: its time is that stage's.
const std::map<std::string, std::string>& stageOf() {
  static const std::map<std::string, std::string> table = {
      {"img_tokens", "image_tokens"}, {"cam_tokens", "pose_estimator"}, {"c2w", "pose_estimator"},
      {"fxfycxcy", "pose_estimator"}, {"ray_tokens", "rays"},           {"dino", "dino_v3"},
      {"cv_drp_input.prob", "cv_drp"}, {"cv_drp_input.binary", "cv_drp"}, {"cv_drp_target.prob", "cv_drp"},
      {"cv_drp_target.binary", "cv_drp"}, {"gated_tokens", "gating"},   {"scene_tokens", "scene_encoder"},
      {"decoder_out", "renderer"},     {"rgb", "renderer"},
      {"lseg_features", "lseg"},       {"semantic_tokens", "semantic_tokens"},
      {"semantic_out_tokens", "renderer"}, {"semantic_features", "renderer"},
      {"text_embeddings", "text_encoder"}, {"label_logits", "labels"}, {"label_maps", "labels"},
      {"refined_input", "sam2_refine"}, {"refined_target", "sam2_refine"}, {"refine_iou", "sam2_refine"},
      {"refine_logits", "sam2_refine"},
  };
  return table;
}

std::string shapeText(const std::vector<int64_t>& shape) {
  std::string s;
  for (int64_t d : shape) s += (s.empty() ? "" : "x") + std::to_string(d);
  return s;
}

bool endsWith(const std::string& s, const std::string& tail) {
  return s.size() >= tail.size() && s.compare(s.size() - tail.size(), tail.size(), tail) == 0;
}

// A mask against the reference's, identical but for near-ties: pixels whose reference value
// (`wantScore`) lies within `band` of its threshold (model/stage_tolerances.h).
void compareMask(SelftestCheck& c, const std::vector<bool>& got, const std::vector<double>& wantMask,
                 const std::vector<double>& wantScore, double threshold, double band) {
  size_t differ = 0, ties = 0, dynamic = 0;
  for (size_t i = 0; i < wantMask.size(); ++i) {
    const bool theirs = wantMask[i] != 0.0;
    dynamic += theirs;
    if (got[i] == theirs) continue;
    if (std::abs(wantScore[i] - threshold) < band) ++ties;
    else ++differ;
  }
  c.nmse = double(differ);  // the count of differing pixels, required 0
  c.detail = std::to_string(differ) + " of " + std::to_string(wantMask.size()) + " pixels differ (" +
             std::to_string(ties) + " near-ties; " + std::to_string(dynamic) + " dynamic)";
}

// Values thresholded on the host (non-finite ones fail the check).
std::vector<bool> above(SelftestCheck& c, const std::vector<float>& values, double threshold) {
  std::vector<bool> out(values.size());
  for (size_t i = 0; i < values.size(); ++i) {
    if (!std::isfinite(values[i])) c.finite = false;
    out[i] = values[i] > threshold;
  }
  return out;
}

// Label maps: the engine's against the reference's, identical but where the reference's two best
// labels nearly tie (reference/label_maps.gap.npy: the top-two gap of its full-resolution scores).
void compareLabelMaps(SelftestCheck& c, const std::vector<int32_t>& got, const std::vector<double>& want,
                      const std::vector<double>& gap) {
  size_t differ = 0, ties = 0;
  for (size_t i = 0; i < want.size(); ++i) {
    if (double(got[i]) == want[i]) continue;
    if (gap[i] < kLabelTieGap) ++ties;
    else ++differ;
  }
  c.nmse = double(differ);  // the count of differing pixels, required 0
  c.detail = std::to_string(differ) + " of " + std::to_string(want.size()) + " pixels differ (" +
             std::to_string(ties) + " near-ties)";
}

nlohmann::json readManifest(const fs::path& dir) {
  std::ifstream in(dir / "manifest.json");
  if (!in) throw Error("cannot read " + (dir / "manifest.json").string());
  try {
    return nlohmann::json::parse(in);
  } catch (const std::exception& e) {
    throw Error((dir / "manifest.json").string() + ": not JSON (" + e.what() + ")");
  }
}

}  // namespace

std::string selftestModelSearchPath(const std::string& explicitDir) {
  if (!explicitDir.empty()) return explicitDir;
  std::string path;
  if (const char* env = std::getenv("SPAR_SELFTEST_DATA"); env && *env) path += std::string(env) + ":";
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (!ec) path += (exe.parent_path().parent_path() / "share" / "spar" / "selftest").string() + ":";
#ifdef SPAR_SELFTEST_SOURCE_DATA
  path += SPAR_SELFTEST_SOURCE_DATA;
#endif
  if (!path.empty() && path.back() == ':') path.pop_back();
  return path;
}

std::string findSelftestModel(const std::string& explicitDir) {
  const std::string path = selftestModelSearchPath(explicitDir);
  size_t start = 0;
  while (start <= path.size()) {
    const size_t end = explicitDir.empty() ? std::min(path.find(':', start), path.size()) : path.size();
    const std::string dir = path.substr(start, end - start);
    std::error_code ec;
    if (!dir.empty() && fs::is_regular_file(fs::path(dir) / "manifest.json", ec)) return dir;
    start = end + 1;
  }
  return "";
}

std::vector<SelftestCheck> runSelftestModel(Engine& engine, const std::string& dirName) {
  std::vector<SelftestCheck> checks;
  const fs::path dir(dirName);
  try {
    const nlohmann::json manifest = readManifest(dir);
    const PackedModel model = PackedModel::open((dir / "model.spar").string());
    SparPipeline pipe(engine, model, {.profile = true, .keepIntermediates = true});
    const SparConfig& config = pipe.config();
    const std::vector<std::string> stages = manifest.at("stages").get<std::vector<std::string>>();
    SparRequest request;
    const int64_t views = manifest.at("views").get<int64_t>();
    request.images = readNpy((dir / "images.npy").string(), {views, 3, config.imageHeight, config.imageWidth}).toFloats();
    request.plan.views = views;
    request.plan.inputs = manifest.at("inputs").get<std::vector<int64_t>>();
    request.plan.targets = manifest.at("targets").get<std::vector<int64_t>>();
    for (const std::string& s : stages) {
      request.targetMotion |= s.rfind("cv_drp_target.", 0) == 0;
      request.refine |= s.rfind("refine", 0) == 0;  // SAM2.1's refinement of every view's mask
    }
    const std::vector<std::string> prompts = manifest.value("prompts", std::vector<std::string>{});
    request.semanticFeatures = config.semanticDecoding() && !prompts.empty();
    const SparEncoded& encoded = pipe.encode(request);
    pipe.renderTargets();
    // SAM2.1's per-view results (inputs, then targets), as the reference lists them.
    std::map<std::string, std::vector<float>> refineOutputs;
    for (const RefinedView& v : encoded.refineViews) {
      refineOutputs["refine_iou"].insert(refineOutputs["refine_iou"].end(), v.iou.begin(), v.iou.end());
      refineOutputs["refine_logits"].insert(refineOutputs["refine_logits"].end(), v.logits.begin(), v.logits.end());
    }

    std::map<std::string, double> stageMs;
    for (const StageTime& t : pipe.stageTimes()) stageMs[t.name] += t.wallMs;
    // The label stages: the reference's token ids (the tokenizer has tests of its own) through
    // CLIP's text tower, then the label maps of the rendered semantic features.
    std::map<std::string, std::vector<float>> labelOutputs;
    std::vector<int32_t> maps;
    if (request.semanticFeatures) {
      const NpyArray tokens = readNpy((dir / "reference" / "text_tokens.npy").string());
      std::vector<int32_t> ids;
      for (double v : tokens.toDoubles()) ids.push_back(int32_t(v));
      const PromptEmbeddings text = encodePrompts(engine, model, config, DType::F32, ids, int64_t(prompts.size()));
      stageMs["text_encoder"] = text.wallMs;
      labelOutputs["text_embeddings"] = engine.download(text.text);
      const auto t = std::chrono::steady_clock::now();
      std::vector<float> scores;
      LabelMapsOut out = computeLabelMaps(engine, pipe.renderedFeatures(), text, &scores);
      stageMs["labels"] = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t).count();
      labelOutputs["label_logits"] = std::move(scores);
      for (const auto& m : out.maps) maps.insert(maps.end(), m.begin(), m.end());
    }
    for (const std::string& name : stages) {
      const auto stage = stageOf().find(name);
      SelftestCheck c{"model " + name, stage == stageOf().end() ? "-" : stage->second};
      c.maxAbsLimit = kUnbounded;  // the model tests bound NMSE; max abs is reported
      try {
        const NpyArray want = readNpy((dir / "reference" / (name + ".npy")).string());
        c.name += " " + shapeText(want.shape);
        if (stage != stageOf().end()) c.ms = stageMs[stage->second];
        if (name == "label_maps") {
          const std::vector<double> gap = readNpy((dir / "reference" / "label_maps.gap.npy").string()).toDoubles();
          if (maps.size() != size_t(want.numel()) || gap.size() != maps.size())
            throw Error(name + ": " + std::to_string(maps.size()) + " pixels, the reference has " +
                        std::to_string(want.numel()));
          c.maxNmse = 0;
          compareLabelMaps(c, maps, want.toDoubles(), gap);
        } else if (endsWith(name, ".binary")) {
          const std::string prob = name.substr(0, name.size() - 7) + ".prob";
          const std::vector<float> got = engine.download(pipe.intermediate(prob));
          const std::vector<double> wantProb = readNpy((dir / "reference" / (prob + ".npy")).string()).toDoubles();
          if (got.size() != size_t(want.numel()) || wantProb.size() != got.size())
            throw Error(name + ": " + std::to_string(got.size()) + " pixels, the reference has " +
                        std::to_string(want.numel()));
          c.maxNmse = 0;
          compareMask(c, above(c, got, config.maskThreshold), want.toDoubles(), wantProb, config.maskThreshold,
                      kMaskTieBand);
        } else if (name == "refined_input" || name == "refined_target") {
          const std::vector<float>& got = name == "refined_input" ? encoded.refinedInput : encoded.refinedTarget;
          const std::vector<double> logits = readNpy((dir / "reference" / (name + ".logits.npy")).string()).toDoubles();
          if (got.size() != size_t(want.numel()) || logits.size() != got.size())
            throw Error(name + ": " + std::to_string(got.size()) + " pixels, the reference has " +
                        std::to_string(want.numel()));
          c.maxNmse = 0;
          compareMask(c, above(c, got, 0.5), want.toDoubles(), logits, 0.0, kRefineTieBand);
        } else {
          const auto label = labelOutputs.find(name);
          const auto refined = refineOutputs.find(name);
          const std::vector<float> got = label != labelOutputs.end()     ? label->second
                                         : refined != refineOutputs.end() ? refined->second
                                                                          : engine.download(pipe.intermediate(name));
          if (got.size() != size_t(want.numel()))
            throw Error(name + ": " + std::to_string(got.size()) + " values, the reference has " +
                        std::to_string(want.numel()));
          c.maxNmse = fp32StageNmseBound(name);
          if (name == "refine_iou") c.maxAbsLimit = kRefineIouMaxAbs;
          measureAgainst(c, got, want.toDoubles());
        }
      } catch (const std::exception& e) {
        c.error = e.what();
      }
      checks.push_back(std::move(c));
    }
  } catch (const std::exception& e) {
    SelftestCheck c{"model " + dir.string(), "-"};
    c.error = e.what();
    checks.push_back(std::move(c));
  }
  return checks;
}

}  // namespace spar::selftest
