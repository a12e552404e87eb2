#include "tools/spar_bench/bench_model.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <map>
#include <vector>

#include "spar/error.h"
#include "spar/session.h"

namespace spar::bench {
namespace {

using Clock = std::chrono::steady_clock;

double msSince(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

// Stage name -> accumulated times (Session::stageTimes() adds up over calls).
std::map<std::string, StageTime> snapshot(const Session& p) {
  std::map<std::string, StageTime> m;
  for (const StageTime& s : p.stageTimes()) m[s.name] = s;
  return m;
}

}  // namespace

std::vector<float> syntheticImages(int64_t views, int64_t height, int64_t width) {
  std::vector<float> images(size_t(views * 3 * height * width));
  for (size_t i = 0; i < images.size(); ++i) {
    // murmur3's 32-bit finalizer of the index (plus a seed): a hash Python repeats exactly
    uint32_t x = uint32_t(i) + 0x9E3779B9u * 12345u;
    x ^= x >> 16;
    x *= 0x85EBCA6Bu;
    x ^= x >> 13;
    x *= 0xC2B2AE35u;
    x ^= x >> 16;
    images[i] = float(x >> 8) * (1.0f / 16777216.0f);
  }
  return images;
}

nlohmann::ordered_json benchModel(const EngineOptions& options, const ModelBenchArgs& a) {
  if (a.views < 1 || a.targets < 0) throw Error("--views must be at least 1 and --targets at least 0");
  const Model model = Model::open(a.model);
  const int64_t h = a.height ? a.height : model.imageHeight(), w = a.width ? a.width : model.imageWidth();
  if (const std::string problem = model.sizeProblem(h, w); !problem.empty()) throw Error(problem);
  if (a.semantic && !model.semantic()) throw Error("this model has no semantic branch: no --semantic");

  Context context(options);
  SessionOptions so;
  so.profile = true;
  so.precision = parsePrecision(a.precision);
  Session pipeline(context, model, so);
  Request req;
  const int64_t v = a.views + a.targets;
  req.images = syntheticImages(v, h, w);
  req.height = h;
  req.width = w;
  req.plan.views = v;
  // inputs first, then the targets (synthetic frames have no order to respect)
  for (int64_t i = 0; i < a.views; ++i) req.plan.inputs.push_back(i);
  for (int64_t i = a.views; i < v; ++i) req.plan.targets.push_back(i);
  req.assumeStatic = a.assumeStatic;
  req.semanticFeatures = a.semantic;

  auto runOnce = [&]() {
    pipeline.encode(req);
    if (a.targets > 0) pipeline.renderTargets();
  };
  // First run: weights uploaded, kernels created and built by the driver.
  auto t = Clock::now();
  runOnce();
  const double firstMs = msSince(t);
  double firstBuildMs = 0;
  for (const StageTime& s : pipeline.stageTimes()) firstBuildMs += s.buildMs;

  const nlohmann::json config = nlohmann::json::parse(model.configJson());
  std::vector<std::string> order;
  for (const StageTime& s : pipeline.stageTimes()) order.push_back(s.name);
  std::map<std::string, std::vector<double>> gpu, wall;
  std::vector<double> totalGpu, totalWall;
  for (int r = 0; r < a.repeats; ++r) {
    const auto before = snapshot(pipeline);
    t = Clock::now();
    runOnce();
    totalWall.push_back(msSince(t));
    double sum = 0;
    for (const auto& [name, s] : snapshot(pipeline)) {
      const auto it = before.find(name);
      const double g = s.gpuMs - (it == before.end() ? 0 : it->second.gpuMs);
      gpu[name].push_back(g);
      wall[name].push_back(s.wallMs - (it == before.end() ? 0 : it->second.wallMs));
      sum += g;
    }
    totalGpu.push_back(sum);
  }
  nlohmann::ordered_json stages = nlohmann::ordered_json::array();
  for (const std::string& name : order)
    stages.push_back({{"name", name}, {"gpu_ms", median(gpu[name])}, {"wall_ms", median(wall[name])}});
  return {{"tool", "spar-bench"},
          {"mode", "model"},
          {"device", context.deviceName()},
          {"model", a.model},
          {"config", {{"d", config.value("d", int64_t(0))}, {"scene_tokens", config.value("scene_tokens", int64_t(0))},
                      {"patch_size", model.patchSize()}}},
          {"request",
           {{"inputs", a.views}, {"targets", a.targets}, {"height", h}, {"width", w}, {"precision", a.precision},
            {"assume_static", a.assumeStatic}, {"semantic", a.semantic}}},
          {"first_run", {{"wall_ms", firstMs}, {"build_ms", firstBuildMs}}},
          {"repeats", a.repeats},
          {"stages", stages},
          {"total", {{"gpu_ms", median(totalGpu)}, {"wall_ms", median(totalWall)}}},
          {"weights_bytes_loaded", pipeline.weightBytesLoaded()},
          {"device_peak_bytes", context.memory().peakBytes}};
}

void printModelBench(const nlohmann::ordered_json& d) {
  const auto& r = d["request"];
  std::printf("spar-bench --model %s: %lld inputs + %lld targets at %lldx%lld, %s%s%s on %s\n",
              d["model"].get<std::string>().c_str(), (long long)r["inputs"].get<int64_t>(),
              (long long)r["targets"].get<int64_t>(), (long long)r["height"].get<int64_t>(),
              (long long)r["width"].get<int64_t>(), r["precision"].get<std::string>().c_str(),
              r["assume_static"].get<bool>() ? ", assume static" : "", r["semantic"].get<bool>() ? ", semantic" : "",
              d["device"].get<std::string>().c_str());
  std::printf("first run (weights, kernel creation and builds): %.1f ms wall, %.1f ms driver builds\n",
              d["first_run"]["wall_ms"].get<double>(), d["first_run"]["build_ms"].get<double>());
  std::printf("%-20s %12s %12s   (median of %d runs)\n", "stage", "GPU ms", "wall ms", d["repeats"].get<int>());
  for (const auto& s : d["stages"])
    std::printf("%-20s %12.3f %12.3f\n", s["name"].get<std::string>().c_str(), s["gpu_ms"].get<double>(),
                s["wall_ms"].get<double>());
  std::printf("%-20s %12.3f %12.3f\n", "total", d["total"]["gpu_ms"].get<double>(), d["total"]["wall_ms"].get<double>());
}

}  // namespace spar::bench
