#include "engine/kernel_tuner.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <vector>

#include "engine/engine.h"
#include "engine/ops/linear.h"
#include "engine/recorder.h"
#include "engine/shader_registry.h"

namespace spar {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// FNV-1a of the GEMM shader's words: a changed kernel is measured again.
std::string shaderHash() {
  uint64_t h = 1469598103934665603ull;
  for (uint32_t w : findShader("gemm_tiled_f32")) {
    h ^= w;
    h *= 1099511628211ull;
  }
  char b[20];
  std::snprintf(b, sizeof(b), "%016llx", static_cast<unsigned long long>(h));
  return b;
}

std::string deviceKey(const DeviceCaps& caps) {
  char b[64];
  std::snprintf(b, sizeof(b), "%04x:%04x driver %u ", caps.vendorId, caps.deviceId, caps.driverVersion);
  return b + caps.name + " (" + caps.driverInfo + ") gemm " + shaderHash();
}

json readChoices(const std::string& file) {
  std::ifstream in(file);
  if (!in) return json::object();
  json j = json::parse(in, nullptr, false);
  return j.is_object() ? j : json::object();
}

std::vector<TiledGemmTiles> candidates(const DeviceCaps& caps) {
  // Common GPU shapes: a small tile of 256 invocations, the classic 128 x 128 / 8 x 8 SGEMM
  // tile, and rectangular ones between them.
  const std::vector<TiledGemmTiles> all = {
      {64, 64, 16, 4, 4}, {128, 128, 8, 8, 8}, {128, 64, 16, 8, 4}, {64, 128, 16, 4, 8}, {128, 128, 16, 8, 8}};
  std::vector<TiledGemmTiles> out;
  for (const auto& t : all) {
    const uint64_t shared = uint64_t(t.bk) * (t.bm + 4 + t.bn + 4) * 4;  // gemm_tiled.comp's tiles
    if (t.invocations() <= int(caps.maxWorkGroupInvocations) && shared <= caps.maxSharedMemory) out.push_back(t);
  }
  return out;
}

// Median compute time of `repeat` runs of one fp32 product with these tiles.
double timeTiles(Engine& engine, KernelPlan& plan, const TiledGemmTiles& tiles, const Tensor& x, const Tensor& w,
                 const Tensor& y, int repeat) {
  plan.gemmTiles = plan.gemmSmallTiles = tiles;
  std::vector<double> ms;
  for (int r = 0; r <= repeat; ++r) {  // the first run builds the pipeline
    Recorder rec(engine, true);
    linear(rec, x, w, Tensor(), y);
    rec.run();
    if (r > 0) ms.push_back(rec.totalMs());
  }
  std::sort(ms.begin(), ms.end());
  return ms[ms.size() / 2];
}

}  // namespace

std::string kernelChoiceFile(const std::string& pipelineCacheFile) {
  if (pipelineCacheFile.empty()) return "";
  return (fs::path(pipelineCacheFile).parent_path() / "kernel-choice.json").string();
}

void chooseGemmTilesByMeasurement(Engine& engine, KernelPlan& plan) {
  const DeviceCaps& caps = engine.caps();
  const std::string file = kernelChoiceFile(engine.options().pipelineCacheFile);
  const std::string key = deviceKey(caps);
  json all = file.empty() ? json::object() : readChoices(file);
  if (all.contains(key)) {
    const json& e = all[key];
    const auto t = e.value("tiles", std::vector<int>{});
    if (t.size() == 5) {
      plan.gemmTiles = {t[0], t[1], t[2], t[3], t[4]};
      plan.source += ", GEMM tiles from " + file + " (measured " + e.value("date", std::string("?")) + ")";
      plan.reasons.push_back("GEMM tiles " + plan.gemmTiles.text() + ": the fastest of " +
                             std::to_string(e.value("candidates", json::array()).size()) + " measured candidates (" + file + ")");
      return;
    }
  }
  const TiledGemmTiles small = plan.gemmSmallTiles;
  // A product big enough to fill a GPU (2048^3: 17 GFLOP, about a millisecond on a large one);
  // a CPU device forced onto the GPU family (tests) measures a small one.
  const int64_t n = caps.isCpu() ? 128 : 2048;
  std::vector<float> values(size_t(n * n));
  for (size_t i = 0; i < values.size(); ++i) values[i] = float((i * 7919) % 1000) / 1000.0f - 0.5f;
  const Tensor x = engine.fromFloats({n, n}, values), w = engine.fromFloats({n, n}, values);
  const Tensor y = engine.tensor({n, n});
  json tried = json::array();
  TiledGemmTiles best = plan.gemmTiles;
  double bestMs = 0;
  const auto t0 = std::chrono::steady_clock::now();
  for (const auto& t : candidates(caps)) {
    const double ms = timeTiles(engine, plan, t, x, w, y, 3);
    tried.push_back({{"tiles", {t.bm, t.bn, t.bk, t.tm, t.tn}}, {"ms", ms}});
    if (bestMs == 0 || ms < bestMs) {
      best = t;
      bestMs = ms;
    }
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  plan.gemmTiles = best;
  plan.gemmSmallTiles = small;
  char date[32];
  const std::time_t now = std::time(nullptr);
  std::strftime(date, sizeof(date), "%Y-%m-%d %H:%M", std::localtime(&now));
  char line[160];
  std::snprintf(line, sizeof(line), "GEMM tiles %s: the fastest of %zu candidates on %lldx%lldx%lld (%.3f ms; measured in %.1f s)",
                best.text().c_str(), tried.size(), static_cast<long long>(n), static_cast<long long>(n),
                static_cast<long long>(n), bestMs, seconds);
  plan.reasons.push_back(line);
  plan.source += ", GEMM tiles measured now";
  if (file.empty()) return;
  all[key] = {{"tiles", {best.bm, best.bn, best.bk, best.tm, best.tn}}, {"date", date}, {"product", n}, {"candidates", tried}};
  std::error_code ec;
  fs::create_directories(fs::path(file).parent_path(), ec);
  const std::string tmp = file + ".tmp";
  {
    std::ofstream out(tmp);
    out << all.dump(1) << "\n";
    if (!out) return;  // an unwritable cache costs a measurement next time, nothing else
  }
  fs::rename(tmp, file, ec);
}

}  // namespace spar
