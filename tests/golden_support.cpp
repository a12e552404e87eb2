#include "golden_support.h"

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <stdexcept>

#include "spar/error.h"

namespace spar::test {

namespace {

// The build's fixture directory, or where the environment variable of the same name points
// (test programs run on another machine, scripts/gpu/gpu-check.sh, with goldens made there).
std::string goldenDir(const char* variable, const char* built) {
  const char* v = std::getenv(variable);
  return v && *v ? v : built;
}

}  // namespace

std::string goldenPath(const std::string& rel) { return goldenDir("SPAR_GOLDENS_DIR", SPAR_GOLDENS_DIR) + "/" + rel; }
std::string tinyModelPath() { return goldenPath("tiny.spar"); }
std::string fullGoldenPath(const std::string& rel) {
  return goldenDir("SPAR_FULL_GOLDENS_DIR", SPAR_FULL_GOLDENS_DIR) + "/" + rel;
}
std::string semanticGoldenPath(const std::string& rel) {
  return goldenDir("SPAR_SEMANTIC_GOLDENS_DIR", SPAR_SEMANTIC_GOLDENS_DIR) + "/" + rel;
}
std::string opGoldenPath(const std::string& rel) {
  return goldenDir("SPAR_OP_GOLDENS_DIR", SPAR_OP_GOLDENS_DIR) + "/" + rel;
}
std::string clipBpePath() {
  const std::string path = goldenDir("SPAR_CLIP_BPE", SPAR_CLIP_BPE);
  if (!std::filesystem::exists(path)) throw std::runtime_error("CLIP BPE merges table not found: " + path);
  return path;
}

GoldenCase::GoldenCase(const std::string& name)
    : name_(name), dir_(!name.empty() && name[0] == '/' ? name : goldenPath(name)) {
  std::ifstream f(dir_ + "/manifest.json");
  if (!f) throw Error(dir_ + "/manifest.json: cannot open (did the spar_goldens fixture run?)");
  manifest_ = nlohmann::json::parse(f);
}

bool GoldenCase::has(const std::string& name) const {
  return std::filesystem::exists(dir_ + "/" + name + ".npy");
}
NpyArray GoldenCase::array(const std::string& name) const { return readNpy(dir_ + "/" + name + ".npy"); }
std::vector<double> GoldenCase::doubles(const std::string& name) const { return array(name).toDoubles(); }
std::vector<float> GoldenCase::floats(const std::string& name) const { return array(name).toFloats(); }
std::vector<int64_t> GoldenCase::shape(const std::string& name) const { return array(name).shape; }
std::vector<int64_t> GoldenCase::inputs() const { return manifest_.at("inputs").get<std::vector<int64_t>>(); }
std::vector<int64_t> GoldenCase::targets() const { return manifest_.at("targets").get<std::vector<int64_t>>(); }
std::vector<std::string> GoldenCase::files() const {
  std::vector<std::string> out;
  for (const auto& o : manifest_.at("order")) out.push_back(o.at("file").get<std::string>());
  return out;
}

}  // namespace spar::test
