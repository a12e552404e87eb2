#include "tools/spar_modes/reference.h"

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "spar/error.h"
#include "formats/npy.h"
#include "tools/common/shell_quote.h"

namespace spar::modes {
namespace {

namespace fs = std::filesystem;

const char* runName(ReferenceRun run) {
  switch (run) {
    case ReferenceRun::Whole: return "whole";
    case ReferenceRun::Static: return "assume-static";
    case ReferenceRun::Refine: return "refine";
    case ReferenceRun::RefinedGating: return "refined-gating";
  }
  return "?";
}

nlohmann::json fileStamp(const std::string& path) {
  if (path.empty()) return nullptr;
  const fs::path p = fs::absolute(path);
  return {p.string(), fs::file_size(p), fs::last_write_time(p).time_since_epoch().count()};
}

// What the goldens were made from: reused only when all of it is unchanged.
nlohmann::json stamp(const ReferenceInputs& in, ReferenceRun run) {
  nlohmann::json files = nlohmann::json::array();
  for (const std::string& f : in.frames) files.push_back(fs::absolute(f).string());
  const bool refine = run == ReferenceRun::Refine || run == ReferenceRun::RefinedGating;
  return {{"checkpoint", fileStamp(in.checkpoint)},
          {"config", in.config},
          {"frames", files},
          {"inputs", in.inputs},
          {"run", runName(run)},
          {"sam2", refine ? fileStamp(in.sam2) : nullptr},
          {"sam2_config", refine ? in.sam2Config : ""},
          {"labels", in.labels},
          {"bpe", in.labels.empty() ? nullptr : fileStamp(in.bpe)},
          {"precision", "fp32"}};
}

std::string joinInputs(const std::vector<int64_t>& v) {
  std::string s;
  for (int64_t i : v) s += (s.empty() ? "" : ",") + std::to_string(i);
  return s;
}

// spar-reference's arguments for one run (after the program name).
std::vector<std::string> goldensArgv(const ReferenceInputs& in, ReferenceRun run, const fs::path& dir) {
  std::vector<std::string> a = {"goldens", "--checkpoint", in.checkpoint};
  if (!in.config.empty()) a.insert(a.end(), {"--config", in.config});
  a.push_back("--frames");
  a.insert(a.end(), in.frames.begin(), in.frames.end());
  a.insert(a.end(), {"--inputs", joinInputs(in.inputs)});
  if (run == ReferenceRun::Static) a.push_back("--assume-static");
  if (run == ReferenceRun::Refine || run == ReferenceRun::RefinedGating) {
    if (in.sam2.empty()) throw Error("the refine modes need the SAM2.1 checkpoint for the reference: give --sam2");
    a.insert(a.end(), {"--sam2", in.sam2});
    if (!in.sam2Config.empty()) a.insert(a.end(), {"--sam2-config", in.sam2Config});
    if (run == ReferenceRun::Refine) a.push_back("--refine");
    else a.insert(a.end(), {"--mask-source", "refined"});
  }
  if (!in.labels.empty()) a.insert(a.end(), {"--labels", in.labels, "--bpe", in.bpe});
  a.insert(a.end(), {"--out", dir.string()});
  return a;
}

// The runs' goldens, made by one spar-reference process (`batch` for more than one run: torch
// is imported once, about 1.5 s a run saved).
void makeGoldens(const ReferenceInputs& in, const std::vector<std::pair<ReferenceRun, fs::path>>& runs,
                 const fs::path& scratch) {
  std::string cmd = shellQuote(in.python) + " " + shellQuote(in.sourceDir + "/reference/spar-reference");
  fs::path batchFile;
  if (runs.size() == 1) {
    for (const std::string& a : goldensArgv(in, runs[0].first, runs[0].second)) cmd += " " + shellQuote(a);
  } else {
    nlohmann::json batch = nlohmann::json::array();
    for (const auto& [run, dir] : runs) batch.push_back(goldensArgv(in, run, dir));
    batchFile = scratch / "reference_batch.json";
    std::ofstream(batchFile) << batch.dump(1) << "\n";
    cmd += " batch " + shellQuote(batchFile.string());
  }
  const int code = std::system(cmd.c_str());
  if (!batchFile.empty()) fs::remove(batchFile);
  if (code != 0) throw Error("the PyTorch reference failed: " + cmd);
}

Reference readReference(ReferenceRun run, const fs::path& dir, bool reused, bool labels) {
  Reference r;
  r.dir = dir.string();
  r.reused = reused;
  // rgb [1, T, 3, H, W]; cv_drp_input.prob / .binary [1, K, 1, H, W]
  r.rgb = readNpy((dir / "rgb.npy").string()).toFloats();
  if (run != ReferenceRun::Static) {
    r.motion = readNpy((dir / "cv_drp_input.prob.npy").string()).toFloats();
    r.mask = readNpy((dir / "cv_drp_input.binary.npy").string()).toFloats();
  }
  if (run == ReferenceRun::Refine || run == ReferenceRun::RefinedGating)  // [1, K, 1, H, W]
    r.refined = readNpy((dir / "refined_input.npy").string()).toFloats();
  if (labels)  // label_maps [R, H, W] of the rendered targets, integer prompt indices
    for (double v : readNpy((dir / "label_maps.npy").string()).toDoubles()) r.labels.push_back(int32_t(v));
  std::ifstream rep(dir / "report.json");
  if (!rep) throw Error(r.dir + "/report.json: cannot open");
  const nlohmann::json report = nlohmann::json::parse(rep);
  for (const auto& s : report.at("stages")) {
    const std::string name = s.at("name");
    if (name != "load_checkpoint" && name != "load_sam2" && name != "prepare_images" && name != "write_outputs")
      r.modelMs += 1000.0 * s.at("seconds").get<double>();
  }
  return r;
}

}  // namespace

std::vector<Reference> loadReferences(const ReferenceInputs& in,
                                      const std::vector<std::pair<ReferenceRun, std::string>>& runs) {
  std::vector<std::pair<ReferenceRun, fs::path>> stale;
  std::vector<bool> reused;
  fs::path scratch;
  for (const auto& [run, dirName] : runs) {
    const fs::path dir = fs::absolute(dirName), stampFile = dir.string() + ".source.json";
    bool same = false;
    if (fs::exists(dir / "manifest.json") && fs::exists(stampFile)) {
      std::ifstream f(stampFile);
      same = nlohmann::json::parse(f, nullptr, false) == stamp(in, run);
    }
    reused.push_back(same);
    std::fprintf(stderr, "spar-modes: PyTorch reference: %s %s\n", same ? "reusing" : "running spar-reference goldens ->",
                 dir.c_str());
    if (same) continue;
    fs::remove_all(dir);
    fs::remove(stampFile);
    fs::create_directories(dir.parent_path());
    scratch = dir.parent_path();
    stale.emplace_back(run, dir);
  }
  if (!stale.empty()) {
    makeGoldens(in, stale, scratch);
    for (const auto& [run, dir] : stale) std::ofstream(dir.string() + ".source.json") << stamp(in, run).dump(1) << "\n";
  }
  std::vector<Reference> out;
  for (size_t i = 0; i < runs.size(); ++i)
    out.push_back(readReference(runs[i].first, fs::absolute(runs[i].second), reused[i], !in.labels.empty()));
  return out;
}

}  // namespace spar::modes
