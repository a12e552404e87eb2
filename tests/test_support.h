// Shared by the op tests: the engine under test (validation layer on), float64 CPU
// reference helpers, error measures, and guarded output tensors.
#pragma once
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>

#include "engine/engine.h"
#include "spar/error.h"
#include "engine/ops/activation.h"
#include "engine/recorder.h"

namespace spar::test {

// A shell word: s in single quotes (for std::system command lines of tests that run programs).
std::string shellQuote(const std::string& s);
// This test process's scratch directory SPAR_TEST_OUT_DIR/<prefix>_<pid> (CTest runs each test
// as its own process): made empty on first use, removed when the process ends unless
// SPAR_KEEP_TEST_OUTPUT is set (to look at the outputs).
const std::filesystem::path& scratchDir(const std::string& prefix);

// A program the test runs (the built `spar`, the Python tools): exit code and what it printed.
struct CommandResult {
  int code = -1;  // exit code; -1 when it did not exit normally
  std::string out, err;
  std::vector<std::string> errLines() const;
};
// Runs argv (each word shell-quoted) with `env` ("NAME=value ..." or "") before it; stdout and
// stderr go through files in `dir`.
CommandResult runCommand(const std::vector<std::string>& argv, const std::filesystem::path& dir,
                         const std::string& env = "");
// A program of ours that opens the engine (the built `spar`, argv[0]) run as runCommand does, with
// the Khronos validation layer and its synchronization validation on (SPAR_VALIDATION=1);
// fails the current test if a validation message was printed.
CommandResult runValidated(const std::vector<std::string>& argv, const std::filesystem::path& dir,
                           const std::string& env = "");
// What ffprobe (Debian's ffmpeg) says of a video's first stream; frames -1 when it could not.
struct VideoInfo {
  std::string codec;
  int width = 0, height = 0, frames = -1;
};
VideoInfo probeVideo(const std::filesystem::path& video, const std::filesystem::path& dir);
// A whole text file ("" when it cannot be read).
std::string readText(const std::filesystem::path& path);

// The engine every test uses; created once with the Khronos validation layer enabled.
Engine& engine();

// Fails the current test if the validation layer reported anything during it.
class EngineTest : public ::testing::Test {
 protected:
  void SetUp() override;
  void TearDown() override;
  Engine& eng() { return engine(); }

 private:
  size_t messagesBefore_ = 0;
};

// SwiftShader's lanes kernels (KernelPlan::gemmLanesSplitK, the convolutions' im2col with it, and
// attentionLanesSplitDim) forced on this device, the CPU family, their constants written into the
// modules: calls body("texel") and body("storage") with the inputs so bound, then restores the
// tuning. Where the device has no subgroup arithmetic with full subgroups (some device-limit
// profiles) it checks instead that the plan refuses them, and calls nothing.
void withLanesKernelsForced(Engine& engine, const std::function<void(const std::string& inputs)>& body);

// Deterministic random values.
std::vector<float> randomUniform(size_t n, float lo, float hi, uint32_t seed);
std::vector<float> randomNormal(size_t n, float mean, float stddev, uint32_t seed);
std::vector<double> toDouble(const std::vector<float>& v);
// Values as an fp16 tensor would hold them (for references of fp16-storage paths).
std::vector<float> roundToHalf(const std::vector<float>& v);

// Multi-head attention in float64 over tensors [B, N, C] with heads at column offsets
// (PyTorch "(nh dh)"): softmax(q k^T * scale, causal mask) v, output [B, Nq, heads * dh].
std::vector<double> attentionRef(const std::vector<float>& q, int64_t qCols, int64_t qOff, const std::vector<float>& k,
                                 int64_t kCols, int64_t kOff, const std::vector<float>& v, int64_t vCols, int64_t vOff,
                                 int64_t B, int64_t Nq, int64_t Nk, int heads, int dh, bool causal, double scale);

// Attention's q / k preparation (engine/ops/attention.h, QkPrep) in float64 on a fused qkv
// [B, N, 3 * heads * dh]: each q and k head RMS-normed (weight: [2, dh], q's then k's; none
// when empty), then rotated by RoPE for tokens t >= prefix (sines, cosines: [N - prefix, dh];
// none when empty). v is copied as it is.
std::vector<double> prepareQkRef(const std::vector<float>& qkv, int64_t B, int64_t N, int heads, int dh,
                                 const std::vector<float>& weight, double eps, const std::vector<float>& sines,
                                 const std::vector<float>& cosines, int64_t prefix);

// The fused activations (shaders/common.glsl) in float64.
double activateRef(double x, Activation act);

// A linear layer in float64: y[b][m][n] = act(sum_k x[b][m][k] w[b or 0][n][k] + bias[n])
// (bias may be empty; batchedW: one weight matrix per batch entry).
std::vector<double> linearRef(const std::vector<float>& x, const std::vector<float>& w, const std::vector<float>& bias,
                              int64_t B, int64_t M, int64_t N, int64_t K, bool batchedW, Activation act);

struct ErrorStats {
  double nmse = 0;     // sum((a-b)^2) / sum(b^2), in double
  double maxAbs = 0;   // max |a-b|
  size_t nonFinite = 0;  // elements of a that are NaN/Inf where b is finite
};
ErrorStats compare(const std::vector<float>& actual, const std::vector<double>& expected);

// Asserts nmse <= maxNmse and maxAbs <= maxAbsErr, no unexpected NaN/Inf; prints both measures.
void expectClose(const std::vector<float>& actual, const std::vector<double>& expected, double maxNmse,
                 double maxAbsErr, const std::string& what = "");

// An output tensor inside a larger buffer: 256 bytes of sentinel words before and after,
// and NaN in the body, so out-of-bounds writes and unwritten elements are both caught.
class GuardedOutput {
 public:
  GuardedOutput(Engine& engine, const Shape& shape, DType dtype = DType::F32);
  const Tensor& tensor() const { return view_; }
  // Reads the body back; fails the test if a guard word changed.
  std::vector<float> read();
  // Fails the test if any body element is still the NaN it was filled with.
  void expectAllWritten();

 private:
  Engine& engine_;
  Tensor whole_, view_;
  size_t guardWords_ = 0;  // 32-bit words before and after
  std::vector<float> body_;
};

// Forces a kernel family (KernelTuning::kernels: "cpu", "gpu", "gpu-fp16", "coopmat") on the
// engine for one scope, restoring its tuning after.
class ScopedKernels {
 public:
  ScopedKernels(Engine& engine, const std::string& family) : engine_(engine), saved_(engine.options().tuning) {
    KernelTuning t = saved_;
    t.kernels = family;
    engine.setTuning(t);
  }
  ~ScopedKernels() { engine_.setTuning(saved_); }
  ScopedKernels(const ScopedKernels&) = delete;
  ScopedKernels& operator=(const ScopedKernels&) = delete;

 private:
  Engine& engine_;
  KernelTuning saved_;
};

// Lowers the device's storage-binding range for one scope so that an op splits its work at a
// small size; restored at restore() or at the end of the scope, so a test that throws midway
// leaves the limit as it found it for the tests after it.
class ScopedBindingRange {
 public:
  ScopedBindingRange(Engine& engine, uint64_t bytes) : device_(engine.device()), saved_(device_.bindingRangeLimit()) {
    device_.setBindingRangeLimitForTesting(bytes);
  }
  ~ScopedBindingRange() { restore(); }
  void restore() { device_.setBindingRangeLimitForTesting(saved_); }
  ScopedBindingRange(const ScopedBindingRange&) = delete;
  ScopedBindingRange& operator=(const ScopedBindingRange&) = delete;

 private:
  Device& device_;
  uint64_t saved_;
};

// Sets an environment variable for one scope (e.g. a tile override such as SPAR_CONV_TILES,
// to test the GPU path on a CPU device), restoring the previous value or absence after.
class ScopedEnv {
 public:
  ScopedEnv(const char* name, const char* value) : name_(name) {
    if (const char* old = std::getenv(name)) old_ = old, had_ = true;
    setenv(name, value, 1);
  }
  ~ScopedEnv() {
    if (had_) setenv(name_, old_.c_str(), 1);
    else unsetenv(name_);
  }
  ScopedEnv(const ScopedEnv&) = delete;
  ScopedEnv& operator=(const ScopedEnv&) = delete;

 private:
  const char* name_;
  std::string old_;
  bool had_ = false;
};

}  // namespace spar::test
