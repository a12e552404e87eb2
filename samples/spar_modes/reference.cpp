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

// What the goldens were made from: reused only when all of it is unchanged.
nlohmann::json stamp(const ReferenceInputs& in, bool assumeStatic) {
  nlohmann::json files = nlohmann::json::array();
  for (const std::string& f : in.frames) files.push_back(fs::absolute(f).string());
  const fs::path ck = fs::absolute(in.checkpoint);
  return {{"checkpoint", ck.string()},
          {"checkpoint_bytes", fs::file_size(ck)},
          {"checkpoint_mtime", fs::last_write_time(ck).time_since_epoch().count()},
          {"config", in.config},
          {"frames", files},
          {"inputs", in.inputs},
          {"assume_static", assumeStatic},
          {"precision", "fp32"}};
}

std::string joinInputs(const std::vector<int64_t>& v) {
  std::string s;
  for (int64_t i : v) s += (s.empty() ? "" : ",") + std::to_string(i);
  return s;
}

void makeGoldens(const ReferenceInputs& in, bool assumeStatic, const fs::path& dir) {
  std::string cmd = quote(in.python) + " " + quote(in.sourceDir + "/reference/spar-reference") + " goldens --checkpoint " +
                    quote(in.checkpoint);
  if (!in.config.empty()) cmd += " --config " + quote(in.config);
  cmd += " --frames";
  for (const std::string& f : in.frames) cmd += " " + quote(f);
  cmd += " --inputs " + joinInputs(in.inputs);
  if (assumeStatic) cmd += " --assume-static";
  cmd += " --out " + quote(dir.string());
  if (std::system(cmd.c_str()) != 0) throw Error("the PyTorch reference failed: " + cmd);
}

}  // namespace

Reference loadReference(const ReferenceInputs& in, bool assumeStatic, const std::string& dirName) {
  const fs::path dir = fs::absolute(dirName), stampFile = dir.string() + ".source.json";
  const nlohmann::json want = stamp(in, assumeStatic);
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
    makeGoldens(in, assumeStatic, dir);
    std::ofstream(stampFile) << want.dump(1) << "\n";
  }
  // rgb [1, T, 3, H, W]; cv_drp_input.prob / .binary [1, K, 1, H, W]
  r.rgb = readNpy((dir / "rgb.npy").string()).toFloats();
  if (!assumeStatic) {
    r.motion = readNpy((dir / "cv_drp_input.prob.npy").string()).toFloats();
    r.mask = readNpy((dir / "cv_drp_input.binary.npy").string()).toFloats();
  }
  std::ifstream rep(dir / "report.json");
  if (!rep) throw Error(r.dir + "/report.json: cannot open");
  const nlohmann::json report = nlohmann::json::parse(rep);
  for (const auto& s : report.at("stages")) {
    const std::string name = s.at("name");
    if (name != "load_checkpoint" && name != "prepare_images" && name != "write_outputs")
      r.modelMs += 1000.0 * s.at("seconds").get<double>();
  }
  return r;
}

}  // namespace spar::modes
