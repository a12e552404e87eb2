// EngineOptions::fromEnvironment and KernelTuning::validate (include/spar/engine_options.h):
// the one place the engine's settings are read from the environment.
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>

#include "spar/engine_options.h"
#include "spar/error.h"

namespace spar {
namespace {

const char* env(const char* name) {
  const char* v = std::getenv(name);
  return v && *v ? v : nullptr;
}

bool flag(const char* name) {
  const char* v = env(name);
  return v && std::string(v) != "0";
}

// "a,b,c[,d,e]" -> N integers, nothing else on the line.
template <size_t N>
std::optional<std::array<int, N>> ints(const char* name, const char* form) {
  const char* v = env(name);
  if (!v) return std::nullopt;
  std::array<int, N> out{};
  const char* p = v;
  for (size_t i = 0; i < N; ++i) {
    char* end = nullptr;
    const long x = std::strtol(p, &end, 10);
    if (end == p || x < -(1L << 20) || x > (1L << 20)) throw Error(std::string(name) + " must be " + form + ", got '" + v + "'");
    out[i] = int(x);
    p = end;
    if (i + 1 < N) {
      if (*p != ',') throw Error(std::string(name) + " must be " + form + ", got '" + v + "'");
      ++p;
    }
  }
  if (*p) throw Error(std::string(name) + " must be " + form + ", got '" + v + "'");
  return out;
}

// A non-negative integer, nothing else.
std::optional<unsigned long long> count(const char* name) {
  const char* v = env(name);
  if (!v) return std::nullopt;
  char* end = nullptr;
  const unsigned long long x = std::strtoull(v, &end, 10);
  if (end == v || *end || *v == '-') throw Error(std::string(name) + " must be a non-negative integer, got '" + v + "'");
  return x;
}

template <size_t N>
void positive(const std::optional<std::array<int, N>>& t, const char* what) {
  if (!t) return;
  for (int x : *t)
    if (x <= 0) throw Error(std::string(what) + " must be " + std::to_string(N) + " positive integers");
}

}  // namespace

void KernelTuning::validate() const {
  positive(gemmTiles, "GEMM tiles (SPAR_GEMM_TILES: RM,RN,LX,LY,KU)");
  positive(attentionTiles, "attention tiles (SPAR_ATTENTION_TILES: QPI,KB,LX)");
  if (attentionTiles && (*attentionTiles)[1] % 4)
    throw Error("attention tiles (SPAR_ATTENTION_TILES): keys per block must be a multiple of 4");
  positive(convTiles, "conv2d tiles (SPAR_CONV_TILES: RC,RY,RX,LX,LY)");
  positive(convTransposeTiles, "conv_transpose2d tiles (SPAR_CONVT_TILES: RC,RY,RX,LX,LY)");
  if (gpuGemmTiles) {
    const auto [bm, bn, bk, tm, tn, pipelined] = *gpuGemmTiles;
    if (bm <= 0 || bn <= 0 || bk <= 0 || tm <= 0 || tn <= 0 || (pipelined != 0 && pipelined != 1))
      throw Error("GPU GEMM tiles (SPAR_GPU_GEMM_TILES: BM,BN,BK,TM,TN,PIPELINED) must be 5 positive integers and 0 or 1");
    if (bm % tm || bn % tn || bk % 4 || (bm / tm) * (bn / tn) > 1024)
      throw Error("GPU GEMM tiles (SPAR_GPU_GEMM_TILES): BM, BN multiples of TM, TN, BK of 4, at most 1024 invocations");
  }
  if (gpuAttentionTiles) {
    const auto [queries, keys, lanes] = *gpuAttentionTiles;
    if (queries <= 0 || keys <= 0 || lanes < 0 || queries > 1024 || keys % 4 ||
        (lanes > 0 && (queries % 4 || keys % lanes || queries / 4 * lanes > 1024)))
      throw Error("GPU attention tiles (SPAR_GPU_ATTENTION_TILES: QUERIES,KEYS,LANES): at most 1024 queries, keys a multiple "
                  "of 4; with LANES > 0 queries a multiple of 4, keys of LANES, at most 1024 invocations");
  }
  if (coopMatTiles) {
    const auto [wm, wn, sgm, sgn, ksteps, pipelined] = *coopMatTiles;
    if (wm <= 0 || wn <= 0 || sgm <= 0 || sgn <= 0 || ksteps <= 0 || (pipelined != 0 && pipelined != 1))
      throw Error("cooperative-matrix GEMM tiles (SPAR_COOPMAT_TILES: WM,WN,SGM,SGN,KSTEPS,PIPELINED) must be 5 positive "
                  "integers and 0 or 1");
  }
  if (!kernels.empty() && kernels != "cpu" && kernels != "gpu" && kernels != "gpu-fp16" && kernels != "coopmat")
    throw Error("kernel family (SPAR_KERNELS) must be cpu, gpu, gpu-fp16 or coopmat, got '" + kernels + "'");
  if (!inputs.empty() && inputs != "texel" && inputs != "storage")
    throw Error("kernel inputs (SPAR_INPUTS) must be texel or storage, got '" + inputs + "'");
  if (gemmRowGroups && (*gemmRowGroups < 0 || *gemmRowGroups > 4096))
    throw Error("GEMM row groups (SPAR_GEMM_ROW_GROUPS) must be 0 to 4096, got " + std::to_string(*gemmRowGroups));
  if (lineGroup) {
    const auto [split, x, y] = *lineGroup;
    if ((split != 0 && split != 1) || x <= 0 || x % 8 || y <= 0)
      throw Error("line group (SPAR_LINE_GROUP) must be SPLIT,LX,LY (SPLIT 0 or 1, LX a positive multiple of 8, LY > 0)");
  }
}

EngineOptions EngineOptions::fromEnvironment(EngineOptions base) {
  EngineOptions o = std::move(base);
  if (o.device.empty())
    if (const char* d = env("SPAR_DEVICE")) o.device = d;
  o.validation = o.validation || flag("SPAR_VALIDATION");
  o.logPipelines = o.logPipelines || flag("SPAR_LOG_PIPELINES");
  o.profileDispatches = o.profileDispatches || flag("SPAR_PROFILE");
  if (auto ms = count("SPAR_SUBMIT_TIMEOUT_MS")) o.submitTimeoutMs = *ms;
  if (auto mb = count("SPAR_MEMORY_LIMIT_MB")) o.memoryLimitBytes = *mb << 20;
  if (o.limits.empty())
    if (const char* l = env("SPAR_DEVICE_LIMITS")) o.limits = DeviceLimits::parse(l);
  if (auto n = count("SPAR_FAULT_ALLOCATION")) o.faults.allocation = *n;
  if (auto n = count("SPAR_FAULT_SUBMISSION")) o.faults.submission = *n;
  KernelTuning& t = o.tuning;
  if (!t.gemmTiles) t.gemmTiles = ints<5>("SPAR_GEMM_TILES", "RM,RN,LX,LY,KU");
  if (!t.attentionTiles) t.attentionTiles = ints<3>("SPAR_ATTENTION_TILES", "QPI,KB,LX");
  if (!t.convTiles) t.convTiles = ints<5>("SPAR_CONV_TILES", "RC,RY,RX,LX,LY");
  if (!t.convTransposeTiles) t.convTransposeTiles = ints<5>("SPAR_CONVT_TILES", "RC,RY,RX,LX,LY");
  if (!t.lineGroup) t.lineGroup = ints<3>("SPAR_LINE_GROUP", "SPLIT,LX,LY");
  if (t.kernels.empty())
    if (const char* k = env("SPAR_KERNELS")) t.kernels = k;
  if (t.inputs.empty())
    if (const char* i = env("SPAR_INPUTS")) t.inputs = i;
  if (!t.gpuGemmTiles) t.gpuGemmTiles = ints<6>("SPAR_GPU_GEMM_TILES", "BM,BN,BK,TM,TN,PIPELINED");
  if (!t.gpuAttentionTiles) t.gpuAttentionTiles = ints<3>("SPAR_GPU_ATTENTION_TILES", "QUERIES,KEYS,LANES");
  if (!t.coopMatTiles) t.coopMatTiles = ints<6>("SPAR_COOPMAT_TILES", "WM,WN,SGM,SGN,KSTEPS,PIPELINED");
  if (!t.measureKernels)
    if (const char* m = env("SPAR_MEASURE_KERNELS")) t.measureKernels = std::string(m) != "0";
  if (!t.gemmLanesSplitK)
    if (const char* g = env("SPAR_GEMM_LANES")) t.gemmLanesSplitK = std::string(g) != "0";
  if (!t.attentionLanesSplitDim)
    if (const char* a = env("SPAR_ATTENTION_LANES")) t.attentionLanesSplitDim = std::string(a) != "0";
  if (!t.gemmRowGroups)
    if (auto g = count("SPAR_GEMM_ROW_GROUPS")) t.gemmRowGroups = int(std::min<unsigned long long>(*g, 1u << 20));
  if (!t.padAliasedRows)
    if (const char* r = env("SPAR_ROW_PADDING")) t.padAliasedRows = std::string(r) != "0";
  if (!t.freezeConstants)
    if (const char* f = env("SPAR_FREEZE_CONSTANTS")) t.freezeConstants = std::string(f) != "0";
  t.validate();
  return o;
}

EngineOptions EngineOptions::fromEnvironment() { return fromEnvironment(EngineOptions{}); }

std::string EngineOptions::defaultPipelineCacheFile() {
  namespace fs = std::filesystem;
  const char* off = env("SPAR_PIPELINE_CACHE");
  if (off && std::string(off) == "0") return "";
  const char* xdg = env("XDG_CACHE_HOME");
  const char* home = env("HOME");
  const fs::path dir = xdg ? fs::path(xdg) / "spar" : home ? fs::path(home) / ".cache" / "spar" : fs::path();
  if (dir.empty()) return "";
  std::error_code ec;
  fs::create_directories(dir, ec);
  return ec ? "" : (dir / "pipelines.bin").string();
}

}  // namespace spar
