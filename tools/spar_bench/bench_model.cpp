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

namespace {

Request syntheticRequest(const ModelBenchArgs& a, int64_t h, int64_t w) {
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
  return req;
}

// A session's runs of the request: the first (weights uploaded, kernels created and built by
// the driver) apart, then `repeats` timed ones; per stage the medians of its GPU and wall time,
// and what one run took in commands (every run records the same).
struct TimedRuns {
  double firstMs = 0, firstBuildMs = 0;
  std::vector<std::string> order;
  std::map<std::string, std::vector<double>> gpu, wall;
  std::map<std::string, StageTime> perRun;  // the last run's share of each stage's counts
  std::vector<double> totalGpu, totalWall;
};

TimedRuns timeRuns(Session& session, const Request& req, int repeats) {
  auto runOnce = [&]() {
    session.encode(req);
    if (!req.plan.targets.empty()) session.renderTargets();
  };
  TimedRuns t;
  auto start = Clock::now();
  runOnce();
  t.firstMs = msSince(start);
  for (const StageTime& s : session.stageTimes()) {
    t.firstBuildMs += s.buildMs;
    t.order.push_back(s.name);
  }
  for (int r = 0; r < repeats; ++r) {
    const auto before = snapshot(session);
    start = Clock::now();
    runOnce();
    t.totalWall.push_back(msSince(start));
    double sum = 0;
    for (const auto& [name, s] : snapshot(session)) {
      const auto it = before.find(name);
      const StageTime b = it == before.end() ? StageTime{} : it->second;
      t.gpu[name].push_back(s.gpuMs - b.gpuMs);
      t.wall[name].push_back(s.wallMs - b.wallMs);
      StageTime& one = t.perRun[name];
      one.dispatches = s.dispatches - b.dispatches;
      one.barriers = s.barriers - b.barriers;
      one.submits = s.submits - b.submits;
      one.transformerBlocks = s.transformerBlocks - b.transformerBlocks;
      one.blockDispatches = s.blockDispatches;  // a maximum, the same every run
      sum += s.gpuMs - b.gpuMs;
    }
    t.totalGpu.push_back(sum);
  }
  return t;
}

nlohmann::ordered_json stagesJson(const TimedRuns& t) {
  nlohmann::ordered_json stages = nlohmann::ordered_json::array();
  for (const std::string& name : t.order) {
    const auto it = t.perRun.find(name);
    const StageTime one = it == t.perRun.end() ? StageTime{} : it->second;
    stages.push_back({{"name", name}, {"gpu_ms", median(t.gpu.count(name) ? t.gpu.at(name) : std::vector<double>{})},
                      {"wall_ms", median(t.wall.count(name) ? t.wall.at(name) : std::vector<double>{})},
                      {"dispatches", one.dispatches}, {"barriers", one.barriers}, {"submits", one.submits},
                      {"transformer_blocks", one.transformerBlocks}, {"block_dispatches", one.blockDispatches}});
  }
  return stages;
}

}  // namespace

nlohmann::ordered_json benchModel(const EngineOptions& options, const ModelBenchArgs& a) {
  if (a.views < 1 || a.targets < 0) throw Error("--views must be at least 1 and --targets at least 0");
  const Model model = Model::open(a.model);
  const int64_t h = a.height ? a.height : model.imageHeight(), w = a.width ? a.width : model.imageWidth();
  if (const std::string problem = model.sizeProblem(h, w); !problem.empty()) throw Error(problem);
  if (a.semantic && !model.semantic()) throw Error("this model has no semantic branch: no --semantic");
  Context context(options);
  SessionOptions so;
  so.precision = parsePrecision(a.precision);
  const Request req = syntheticRequest(a, h, w);
  TimedRuns profiled, unprofiled;
  uint64_t weightBytes = 0;
  {
    so.profile = true;  // per-dispatch timestamps: each stage's GPU time
    Session session(context, model, so);
    profiled = timeRuns(session, req, a.repeats);
    weightBytes = session.weightBytesLoaded();
  }
  {
    // What a user waits for: the same runs with no timestamp between dispatches.
    so.profile = false;
    Session session(context, model, so);
    unprofiled = timeRuns(session, req, a.repeats);
  }
  const nlohmann::json config = nlohmann::json::parse(model.configJson());
  return {{"tool", "spar-bench"},
          {"mode", "model"},
          {"device", context.deviceName()},
          {"model", a.model},
          {"config", {{"d", config.value("d", int64_t(0))}, {"scene_tokens", config.value("scene_tokens", int64_t(0))},
                      {"patch_size", model.patchSize()}}},
          {"request",
           {{"inputs", a.views}, {"targets", a.targets}, {"height", h}, {"width", w}, {"precision", a.precision},
            {"assume_static", a.assumeStatic}, {"semantic", a.semantic}}},
          {"first_run", {{"wall_ms", profiled.firstMs}, {"build_ms", profiled.firstBuildMs}}},
          {"repeats", a.repeats},
          {"stages", stagesJson(profiled)},
          {"total",
           {{"gpu_ms", median(profiled.totalGpu)},
            {"wall_ms", median(profiled.totalWall)},
            {"wall_ms_unprofiled", median(unprofiled.totalWall)}}},
          {"weights_bytes_loaded", weightBytes},
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
  std::printf("%-20s %12s %12s %10s %9s %8s %7s %9s   (median of %d runs)\n", "stage", "GPU ms", "wall ms", "dispatches",
              "barriers", "submits", "blocks", "per block", d["repeats"].get<int>());
  for (const auto& s : d["stages"])
    std::printf("%-20s %12.3f %12.3f %10llu %9llu %8llu %7llu %9llu\n", s["name"].get<std::string>().c_str(),
                s["gpu_ms"].get<double>(), s["wall_ms"].get<double>(), (unsigned long long)s["dispatches"].get<uint64_t>(),
                (unsigned long long)s["barriers"].get<uint64_t>(), (unsigned long long)s["submits"].get<uint64_t>(),
                (unsigned long long)s["transformer_blocks"].get<uint64_t>(),
                (unsigned long long)s["block_dispatches"].get<uint64_t>());
  std::printf("%-20s %12.3f %12.3f   (without timestamps: %.3f ms wall)\n", "total", d["total"]["gpu_ms"].get<double>(),
              d["total"]["wall_ms"].get<double>(), d["total"]["wall_ms_unprofiled"].get<double>());
}

}  // namespace spar::bench
