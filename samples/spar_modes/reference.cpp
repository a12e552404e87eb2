#include "samples/spar_modes/reference.h"

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "engine/error.h"
#include "formats/npy.h"

namespace spar::modes {
namespace {

namespace fs = std::filesystem;

std::string quote(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

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
          {"precision", "fp32"}};
}

std::string joinInputs(const std::vector<int64_t>& v) {
  std::string s;
  for (int64_t i : v) s += (s.empty() ? "" : ",") + std::to_string(i);
  return s;
}

void makeGoldens(const ReferenceInputs& in, ReferenceRun run, const fs::path& dir) {
  std::string cmd = quote(in.python) + " " + quote(in.sourceDir + "/reference/spar-reference") + " goldens --checkpoint " +
                    quote(in.checkpoint);
  if (!in.config.empty()) cmd += " --config " + quote(in.config);
  cmd += " --frames";
  for (const std::string& f : in.frames) cmd += " " + quote(f);
  cmd += " --inputs " + joinInputs(in.inputs);
  if (run == ReferenceRun::Static) cmd += " --assume-static";
  if (run == ReferenceRun::Refine || run == ReferenceRun::RefinedGating) {
    if (in.sam2.empty()) throw Error("the refine modes need the SAM2.1 checkpoint for the reference: give --sam2");
    cmd += " --sam2 " + quote(in.sam2);
    if (!in.sam2Config.empty()) cmd += " --sam2-config " + quote(in.sam2Config);
    cmd += run == ReferenceRun::Refine ? " --refine" : " --mask-source refined";
  }
  cmd += " --out " + quote(dir.string());
  if (std::system(cmd.c_str()) != 0) throw Error("the PyTorch reference failed: " + cmd);
}

}  // namespace

Reference loadReference(const ReferenceInputs& in, ReferenceRun run, const std::string& dirName) {
  const fs::path dir = fs::absolute(dirName), stampFile = dir.string() + ".source.json";
  const nlohmann::json want = stamp(in, run);
  const bool assumeStatic = run == ReferenceRun::Static;
  Reference r;
  r.dir = dir.string();
  if (fs::exists(dir / "manifest.json") && fs::exists(stampFile)) {
    std::ifstream f(stampFile);
    r.reused = nlohmann::json::parse(f, nullptr, false) == want;
  }
  std::fprintf(stderr, "spar-modes: PyTorch reference: %s %s\n", r.reused ? "reusing" : "running spar-reference goldens ->",
               r.dir.c_str());
  if (!r.reused) {
    fs::remove_all(dir);
    fs::remove(stampFile);
    fs::create_directories(dir.parent_path());
    makeGoldens(in, run, dir);
    std::ofstream(stampFile) << want.dump(1) << "\n";
  }
  // rgb [1, T, 3, H, W]; cv_drp_input.prob / .binary [1, K, 1, H, W]
  r.rgb = readNpy((dir / "rgb.npy").string()).toFloats();
  if (!assumeStatic) {
    r.motion = readNpy((dir / "cv_drp_input.prob.npy").string()).toFloats();
    r.mask = readNpy((dir / "cv_drp_input.binary.npy").string()).toFloats();
  }
  if (run == ReferenceRun::Refine || run == ReferenceRun::RefinedGating)  // [1, K, 1, H, W]
    r.refined = readNpy((dir / "refined_input.npy").string()).toFloats();
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

}  // namespace spar::modes
