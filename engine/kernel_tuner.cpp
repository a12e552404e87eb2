#include "engine/kernel_tuner.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <functional>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include <unistd.h>

#include "engine/engine.h"
#include "engine/ops/attention.h"
#include "engine/ops/linear.h"
#include "engine/recorder.h"
#include "engine/shader_registry.h"

namespace spar {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// FNV-1a of the measured shaders' words: a changed kernel is measured again.
std::string shaderHash() {
  uint64_t h = 1469598103934665603ull;
  for (const char* name : {"gemm_tiled_f32", "attention_tiled_f32", "attention_flash_f32", "attention_flash_sg_f32", "gemm_coopmat_f32"})
    for (uint32_t w : findShader(name)) {
      h ^= w;
      h *= 1099511628211ull;
    }
  char b[20];
  std::snprintf(b, sizeof(b), "%016llx", static_cast<unsigned long long>(h));
  return b;
}

// The fp32 GEMM candidates are timed on the four products of one transformer block at the
// official model's width (D 768, MLP 3072) over 2048 tokens: qkv, fc, MLP up, MLP down. Their
// aspect ratios, not a square's, decide which tiles fill a GPU: a 768-wide output is 6 columns
// of 128-wide tiles, so 2048 x 768 gives 96 such workgroups where 2048^3 gave 256. A CPU device
// forced onto the GPU family (tests) times a block of width 64 over 128 tokens.
struct Product {
  int64_t m, n, k;
};
std::vector<Product> blockProducts(bool cpu) {
  const int64_t tokens = cpu ? 128 : 2048, d = cpu ? 64 : 768, hidden = 4 * d;
  return {{tokens, 3 * d, d}, {tokens, d, d}, {tokens, hidden, d}, {tokens, d, hidden}};
}
const char* kWorkload = "block 768 / 3072 x 2048 tokens";  // in the cache key: another workload is measured anew

std::string deviceKey(const DeviceCaps& caps) {
  char b[64];
  std::snprintf(b, sizeof(b), "%04x:%04x driver %u ", caps.vendorId, caps.deviceId, caps.driverVersion);
  return b + caps.name + " (" + caps.driverInfo + ") kernels " + shaderHash() + ", " + kWorkload;
}

json readChoices(const std::string& file) {
  std::ifstream in(file);
  if (!in) return json::object();
  json j = json::parse(in, nullptr, false);
  return j.is_object() ? j : json::object();
}

// The fastest of `count` candidates: apply(i) puts candidate i into the plan, record(rec)
// records the measured work; each is run once to build its pipeline, then `repeat` times.
struct Fastest {
  size_t index = 0;
  double ms = 0;
  json tried = json::array();
};
Fastest fastest(Engine& engine, size_t count, const std::function<json(size_t)>& apply,
                const std::function<void(Recorder&)>& record, int repeat) {
  Fastest f;
  for (size_t i = 0; i < count; ++i) {
    const json label = apply(i);
    std::vector<double> ms;
    for (int r = 0; r <= repeat; ++r) {
      Recorder rec(engine, true);
      record(rec);
      rec.run();
      if (r > 0) ms.push_back(rec.totalMs());
    }
    std::sort(ms.begin(), ms.end());
    const double median = ms[ms.size() / 2];
    f.tried.push_back({{"tiles", label}, {"ms", median}});
    if (i == 0 || median < f.ms) f.index = i, f.ms = median;
  }
  return f;
}

std::vector<float> pattern(size_t n) {
  std::vector<float> v(n);
  for (size_t i = 0; i < n; ++i) v[i] = float((i * 7919) % 1000) / 1000.0f - 0.5f;
  return v;
}

void applyCached(KernelPlan& plan, const json& e, const std::string& file) {
  const auto g = e.at("gemm").value("tiles", std::vector<int>{});
  const auto a = e.at("attention").value("tiles", std::vector<int>{});
  if (g.size() != 6 || a.size() != 3) throw std::runtime_error("malformed entry");
  if (plan.gemmF16 == KernelFamily::CoopMat) {
    const auto c = e.at("coopmat").value("tiles", std::vector<int>{});
    if (c.size() != 6) throw std::runtime_error("malformed entry");
    plan.coop.wm = c[0], plan.coop.wn = c[1], plan.coop.sgM = c[2], plan.coop.sgN = c[3], plan.coop.kSteps = c[4];
    plan.coop.pipelined = c[5] != 0;
  }
  plan.gemmTiles = {g[0], g[1], g[2], g[3], g[4], g[5] != 0};
  plan.attentionQueries = a[0];
  plan.attentionKeys = a[1];
  plan.attentionLanes = a[2];
  plan.source += ", tiles from " + file + " (measured " + e.value("date", std::string("?")) + ")";
  plan.reasons.push_back("GEMM tiles " + plan.gemmTiles.text() + ", " + attentionText(plan) +
                         ": the fastest measured candidates (" + file + ")");
}

}  // namespace

std::vector<TiledGemmTiles> gemmTileCandidates(const DeviceCaps& caps) {
  // Common GPU shapes: a small tile of 256 invocations, the classic 128 x 128 / 8 x 8 SGEMM
  // tile, and rectangular ones between them.
  // The first is the kernel as it was before prefetching and interleaving (one k step at a
  // time), so a device where those do not pay keeps it.
  const std::vector<TiledGemmTiles> all = {{64, 64, 16, 4, 4, false}, {64, 64, 16, 4, 4},    {128, 128, 8, 8, 8},
                                           {128, 64, 16, 8, 4},       {64, 128, 16, 4, 8}, {128, 128, 16, 8, 8}};
  std::vector<TiledGemmTiles> out;
  for (const auto& t : all) {
    const uint64_t shared = uint64_t(t.bk) * (t.bm + 4 + t.bn + 4) * 4;  // gemm_tiled.comp's tiles
    if (t.invocations() <= int(caps.maxWorkGroupInvocations) && shared <= caps.maxSharedMemory) out.push_back(t);
  }
  return out;
}

// (queries a workgroup, keys a block, lanes) for 64-wide heads: attention_tiled.comp's blocks
// (lanes 0, one query an invocation) and attention_flash.comp's (lanes invocations sharing 4
// queries: from 64 to 256 invocations, 2-4 keys and 1-2 output texels a lane), those that fit.
std::vector<std::array<int, 3>> attentionBlockCandidates(const DeviceCaps& caps) {
  const std::vector<std::array<int, 3>> all = {{64, 32, 0},  {128, 32, 0}, {64, 64, 0}, {32, 32, 16},
                                               {64, 32, 16}, {32, 32, 8},  {64, 32, 8}, {16, 64, 16}};
  std::vector<std::array<int, 3>> out;
  for (const auto& [queries, keys, lanes] : all) {
    const int invocations = lanes ? queries / 4 * lanes : queries;
    const uint64_t shared = lanes ? attentionFlashSharedBytes(queries, keys, lanes, 64) : uint64_t(keys) * 64 * 8;
    if (invocations <= int(caps.maxWorkGroupInvocations) && shared <= caps.maxSharedMemory)
      out.push_back({queries, keys, lanes});
  }
  return out;
}

// gemm_coopmat.comp's workgroup shapes (MMAs per subgroup WM x WN, subgroups SG_M x SG_N, K
// blocks a step) that fit the device.
std::vector<CoopMatTiles> coopMatTileCandidates(const DeviceCaps& caps, const CoopMatTiles& base) {
  // The first: the kernel as it was before prefetching (PIPELINED 0), kept as a candidate.
  const std::vector<std::array<int, 6>> all = {{2, 2, 2, 2, 2, 0}, {2, 2, 2, 2, 2, 1}, {4, 2, 2, 2, 2, 1},
                                               {2, 4, 2, 2, 2, 1}, {4, 4, 2, 2, 1, 1}, {4, 4, 2, 2, 2, 1},
                                               {2, 2, 4, 2, 2, 1}};
  std::vector<CoopMatTiles> out;
  for (const auto& a : all) {
    CoopMatTiles t = base;
    t.wm = a[0], t.wn = a[1], t.sgM = a[2], t.sgN = a[3], t.kSteps = a[4], t.pipelined = a[5] != 0;
    if (t.fits(caps)) out.push_back(t);
  }
  return out;
}

std::string kernelChoiceFile(const std::string& pipelineCacheFile) {
  if (pipelineCacheFile.empty()) return "";
  return (fs::path(pipelineCacheFile).parent_path() / "kernel-choice.json").string();
}

void measureKernelChoice(Engine& engine, KernelPlan& plan) {
  const DeviceCaps& caps = engine.caps();
  const std::string file = kernelChoiceFile(engine.options().pipelineCacheFile);
  const std::string key = deviceKey(caps);
  json all = file.empty() ? json::object() : readChoices(file);
  if (all.contains(key)) {
    try {
      applyCached(plan, all[key], file);
      return;
    } catch (const std::exception&) {  // an entry of another layout: measured again
    }
  }
  const auto t0 = std::chrono::steady_clock::now();
  // Work big enough to fill a GPU (a transformer block's products, blockProducts; the fp16
  // cooperative-matrix GEMM on a 2048^3 product; 8 heads of 64 over 2048 tokens); a CPU device
  // forced onto the GPU family (tests) measures small ones.
  const int64_t n = caps.isCpu() ? 128 : 2048;
  const std::vector<float> square = pattern(size_t(n * n));
  const Tensor y = engine.tensor({n, n});
  struct Bound {
    Tensor x, w, y;
  };
  std::vector<Bound> block;
  for (const Product& p : blockProducts(caps.isCpu()))
    block.push_back({engine.fromFloats({p.m, p.k}, pattern(size_t(p.m * p.k))),
                     engine.fromFloats({p.n, p.k}, pattern(size_t(p.n * p.k))), engine.tensor({p.m, p.n})});
  const TiledGemmTiles small = plan.gemmSmallTiles;
  const auto gemms = gemmTileCandidates(caps);
  const Fastest g = fastest(
      engine, gemms.size(),
      [&](size_t i) {
        plan.gemmTiles = plan.gemmSmallTiles = gemms[i];
        const auto& t = gemms[i];
        return json{t.bm, t.bn, t.bk, t.tm, t.tn, t.pipelined ? 1 : 0};
      },
      [&](Recorder& rec) {
        for (const Bound& b : block) linear(rec, b.x, b.w, Tensor(), b.y);
      },
      3);
  plan.gemmTiles = gemms[g.index];
  plan.gemmSmallTiles = small;

  const int heads = 8, dh = 64;
  const int64_t tokens = caps.isCpu() ? 64 : 2048;
  const Tensor qkv = engine.fromFloats({tokens, 3 * heads * dh}, pattern(size_t(tokens * 3 * heads * dh)));
  const Tensor out = engine.tensor({tokens, heads * dh});
  const auto atts = attentionBlockCandidates(caps);
  const Fastest a = fastest(
      engine, atts.size(),
      [&](size_t i) {
        plan.attentionQueries = atts[i][0];
        plan.attentionKeys = atts[i][1];
        plan.attentionLanes = atts[i][2];
        return json{atts[i][0], atts[i][1], atts[i][2]};
      },
      [&](Recorder& rec) { attention(rec, {qkv, 0}, {qkv, heads * dh}, {qkv, 2 * heads * dh}, {out, 0}, heads, dh); }, 3);
  plan.attentionQueries = atts[a.index][0];
  plan.attentionKeys = atts[a.index][1];
  plan.attentionLanes = atts[a.index][2];

  // fp16 weights on cooperative matrices: the workgroup shape, on an fp16 product.
  Fastest c;
  std::vector<CoopMatTiles> coops;
  if (plan.gemmF16 == KernelFamily::CoopMat) {
    const Tensor x16 = engine.fromFloats({n, n}, square, DType::F16), w16 = engine.fromFloats({n, n}, square, DType::F16);
    coops = coopMatTileCandidates(caps, plan.coop);
    c = fastest(
        engine, coops.size(),
        [&](size_t i) {
          plan.coop = coops[i];
          return json{coops[i].wm, coops[i].wn, coops[i].sgM, coops[i].sgN, coops[i].kSteps, coops[i].pipelined ? 1 : 0};
        },
        [&](Recorder& rec) { linear(rec, x16, w16, Tensor(), y); }, 3);
    plan.coop = coops[c.index];
  }

  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  char line[200];
  std::snprintf(line, sizeof(line),
                "GEMM tiles %s (%.3f ms on a transformer block's 4 products, %s), attention %d queries / %d keys / "
                "%d lanes (%.3f ms, %d heads x %d over %lld tokens): the fastest of %zu and %zu candidates, measured in %.1f s",
                plan.gemmTiles.text().c_str(), g.ms, caps.isCpu() ? "64 / 256 x 128 tokens" : kWorkload, plan.attentionQueries,
                plan.attentionKeys, plan.attentionLanes, a.ms, heads, dh, static_cast<long long>(tokens), gemms.size(),
                atts.size(), seconds);
  plan.reasons.push_back(line);
  if (!coops.empty())
    plan.reasons.push_back("cooperative-matrix GEMM " + plan.coop.text() + ": the fastest of " +
                           std::to_string(coops.size()) + " workgroup shapes on an fp16 " + std::to_string(n) + "^3 product");
  plan.source += ", tiles measured now";
  if (file.empty()) return;
  char date[32];
  const std::time_t now = std::time(nullptr);
  std::strftime(date, sizeof(date), "%Y-%m-%d %H:%M", std::localtime(&now));
  all[key] = {{"date", date},
              {"gemm", {{"tiles", g.tried[g.index]["tiles"]}, {"workload", kWorkload}, {"candidates", g.tried}}},
              {"attention", {{"tiles", a.tried[a.index]["tiles"]}, {"tokens", tokens}, {"candidates", a.tried}}}};
  if (!coops.empty()) all[key]["coopmat"] = {{"tiles", c.tried[c.index]["tiles"]}, {"candidates", c.tried}};
  std::error_code ec;
  fs::create_directories(fs::path(file).parent_path(), ec);
  const std::string tmp = file + ".tmp-" + std::to_string(::getpid());  // processes may save at once
  {
    std::ofstream o(tmp);
    o << all.dump(1) << "\n";
    if (!o) return;  // an unwritable cache costs a measurement next time, nothing else
  }
  fs::rename(tmp, file, ec);
}

}  // namespace spar
