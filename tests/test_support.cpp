#include "tests/test_support.h"

#include <sys/wait.h>

#include <algorithm>
#include <fstream>
#include <sstream>
#include <cstring>

#include "engine/half.h"
#include "engine/uniform_floats.h"

namespace spar::test {
namespace {

Engine* gEngine = nullptr;
constexpr uint32_t kGuardWord = 0x7fc0beefu;  // a quiet NaN with a recognizable payload
constexpr uint32_t kUnwrittenWord = 0x7fc0dead;

}  // namespace

Engine& engine() {
  if (!gEngine) {
    EngineOptions options;
    options.validation = true;
    options.verbose = true;
    gEngine = new Engine(EngineOptions::fromEnvironment(options));  // lives until exit: tests share pipelines
  }
  return *gEngine;
}

void EngineTest::SetUp() { messagesBefore_ = engine().device().validationMessageCount(); }

void EngineTest::TearDown() {
  const size_t now = engine().device().validationMessageCount();
  EXPECT_EQ(now, messagesBefore_) << "the Vulkan validation layer reported " << (now - messagesBefore_)
                                  << " message(s) during this test";
}

std::vector<float> randomUniform(size_t n, float lo, float hi, uint32_t seed) {
  std::mt19937 rng(seed);
  std::vector<float> v(n);
  for (auto& x : v) x = uniformFloat(rng, lo, hi);
  return v;
}

std::vector<float> randomNormal(size_t n, float mean, float stddev, uint32_t seed) {
  std::mt19937 rng(seed);
  NormalFloats dist(mean, stddev);
  std::vector<float> v(n);
  for (auto& x : v) x = dist(rng);
  return v;
}

std::vector<double> toDouble(const std::vector<float>& v) { return {v.begin(), v.end()}; }

std::vector<float> roundToHalf(const std::vector<float>& v) {
  std::vector<float> out(v.size());
  for (size_t i = 0; i < v.size(); ++i) out[i] = halfToFloat(floatToHalf(v[i]));
  return out;
}

double activateRef(double x, Activation act) {
  switch (act) {
    case Activation::Gelu: return 0.5 * x * std::erfc(-x / std::sqrt(2.0));
    case Activation::QuickGelu: return x / (1.0 + std::exp(-1.702 * x));
    case Activation::Silu: return x / (1.0 + std::exp(-x));
    case Activation::Sigmoid: return 1.0 / (1.0 + std::exp(-x));
    case Activation::Relu: return std::max(x, 0.0);
    default: return x;
  }
}

ErrorStats compare(const std::vector<float>& actual, const std::vector<double>& expected) {
  ErrorStats s;
  double num = 0, den = 0;
  for (size_t i = 0; i < actual.size() && i < expected.size(); ++i) {
    if (!std::isfinite(actual[i])) {
      if (std::isfinite(expected[i]) || std::isnan(actual[i]) != std::isnan(expected[i])) ++s.nonFinite;
      continue;
    }
    const double d = double(actual[i]) - expected[i];
    num += d * d;
    den += expected[i] * expected[i];
    s.maxAbs = std::max(s.maxAbs, std::abs(d));
  }
  s.nmse = den > 0 ? num / den : num;
  return s;
}

void expectClose(const std::vector<float>& actual, const std::vector<double>& expected, double maxNmse,
                 double maxAbsErr, const std::string& what) {
  ASSERT_EQ(actual.size(), expected.size()) << what;
  ErrorStats s = compare(actual, expected);
  std::printf("    %-28s nmse %.3e  max abs %.3e\n", what.c_str(), s.nmse, s.maxAbs);
  EXPECT_EQ(s.nonFinite, 0u) << what << ": NaN/Inf where the reference is finite";
  EXPECT_LE(s.nmse, maxNmse) << what;
  EXPECT_LE(s.maxAbs, maxAbsErr) << what;
}

GuardedOutput::GuardedOutput(Engine& engine, const Shape& shape, DType dtype) : engine_(engine) {
  const size_t elemBytes = dtypeSize(dtype);
  const size_t guardBytes = 256;
  guardWords_ = guardBytes / 4;
  const size_t bodyBytes = static_cast<size_t>(shapeNumel(shape)) * elemBytes;
  const size_t bodyPadded = (bodyBytes + 3) / 4 * 4;
  const size_t totalWords = 2 * guardWords_ + bodyPadded / 4;
  whole_ = engine.tensor({static_cast<int64_t>(totalWords)}, DType::I32);
  std::vector<uint32_t> init(totalWords, kGuardWord);
  if (dtype == DType::F16) {
    std::vector<uint16_t> body(bodyPadded / 2, 0x7e01);  // fp16 NaN
    std::memcpy(init.data() + guardWords_, body.data(), bodyPadded);
  } else {
    for (size_t i = 0; i < bodyPadded / 4; ++i) init[guardWords_ + i] = kUnwrittenWord;
  }
  engine.write(whole_, init.data(), init.size() * 4);
  Tensor typed(whole_.bufferPtr(), whole_.byteOffset(), {static_cast<int64_t>(totalWords * 4 / elemBytes)}, dtype);
  view_ = typed.view(static_cast<int64_t>(guardBytes / elemBytes), {shapeNumel(shape)}).reshape(shape);
}

std::vector<float> GuardedOutput::read() {
  std::vector<uint32_t> words(static_cast<size_t>(whole_.numel()));
  engine_.read(whole_, words.data(), words.size() * 4);
  size_t bad = 0;
  for (size_t i = 0; i < guardWords_; ++i) {
    bad += words[i] != kGuardWord;
    bad += words[words.size() - 1 - i] != kGuardWord;
  }
  // Padding words after an odd-length fp16 body also count as guard on their half.
  EXPECT_EQ(bad, 0u) << "kernel wrote outside its output tensor";
  body_ = engine_.download(view_);
  return body_;
}

void GuardedOutput::expectAllWritten() {
  if (body_.empty()) read();
  size_t unwritten = 0;
  for (float v : body_) unwritten += std::isnan(v);
  EXPECT_EQ(unwritten, 0u) << "elements left unwritten (or NaN)";
}

std::string shellQuote(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

namespace {
struct ScratchDir {
  std::filesystem::path path;
  explicit ScratchDir(const std::string& prefix)
      : path(std::filesystem::path(SPAR_TEST_OUT_DIR) / (prefix + "_" + std::to_string(::getpid()))) {
    std::filesystem::remove_all(path);
    std::filesystem::create_directories(path);
  }
  ~ScratchDir() {
    std::error_code ec;
    if (!std::getenv("SPAR_KEEP_TEST_OUTPUT")) std::filesystem::remove_all(path, ec);
  }
};
}  // namespace

const std::filesystem::path& scratchDir(const std::string& prefix) {
  static const ScratchDir d(prefix);  // one per process: each test executable uses one prefix
  return d.path;
}

std::vector<std::string> CommandResult::errLines() const {
  std::vector<std::string> lines;
  std::stringstream ss(err);
  for (std::string l; std::getline(ss, l);) lines.push_back(l);
  return lines;
}

std::string readText(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

CommandResult runCommand(const std::vector<std::string>& argv, const std::filesystem::path& dir,
                         const std::string& env) {
  const std::filesystem::path outFile = dir / "command_stdout.txt", errFile = dir / "command_stderr.txt";
  std::string cmd = env.empty() ? "" : env + " ";
  for (const auto& a : argv) cmd += shellQuote(a) + " ";
  cmd += "> " + shellQuote(outFile.string()) + " 2> " + shellQuote(errFile.string());
  const int status = std::system(cmd.c_str());
  CommandResult r;
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = readText(outFile);
  r.err = readText(errFile);
  return r;
}

CommandResult runValidated(const std::vector<std::string>& argv, const std::filesystem::path& dir,
                           const std::string& env) {
  const CommandResult r = runCommand(argv, dir, "SPAR_VALIDATION=1" + (env.empty() ? "" : " " + env));
  // The engine's messenger prefixes "[vulkan validation]"; the layer's own log says VUID / Validation.
  for (const std::string* s : {&r.out, &r.err})
    for (const char* mark : {"[vulkan validation]", "VUID", "Validation"})
      EXPECT_EQ(s->find(mark), std::string::npos) << "validation message from " << argv[0] << ":\n" << *s;
  return r;
}

void withLanesKernelsForced(Engine& engine, const std::function<void(const std::string& inputs)>& body) {
  const DeviceCaps& caps = engine.caps();
  const KernelTuning saved = engine.options().tuning;
  KernelTuning t = saved;
  t.kernels = "cpu";  // the CPU family's kernels, also in a program's GPU-family run
  t.gemmLanesSplitK = true;
  t.attentionLanesSplitDim = true;
  if (!(caps.subgroupArithmetic && caps.fullSubgroups)) {
    EXPECT_THROW(engine.setTuning(t), Error);
    return;
  }
  t.freezeConstants = true;
  for (const char* inputs : {"texel", "storage"}) {
    t.inputs = inputs;
    engine.setTuning(t);
    EXPECT_TRUE(engine.plan().gemmLanesSplitK && engine.plan().attentionLanesSplitDim);
    body(inputs);
  }
  engine.setTuning(saved);
}

VideoInfo probeVideo(const std::filesystem::path& video, const std::filesystem::path& dir) {
  const CommandResult r = runCommand({"ffprobe", "-v", "error", "-select_streams", "v:0", "-count_frames",
                                      "-show_entries", "stream=codec_name,width,height,nb_read_frames", "-of",
                                      "default=noprint_wrappers=1", video.string()},
                                     dir);
  VideoInfo v;
  EXPECT_EQ(r.code, 0) << "ffprobe " << video << ": " << r.err;
  std::stringstream ss(r.out);
  for (std::string line; std::getline(ss, line);) {
    const size_t eq = line.find('=');
    if (eq == std::string::npos) continue;
    const std::string key = line.substr(0, eq), value = line.substr(eq + 1);
    if (key == "codec_name") v.codec = value;
    if (key == "width") v.width = std::atoi(value.c_str());
    if (key == "height") v.height = std::atoi(value.c_str());
    if (key == "nb_read_frames") v.frames = std::atoi(value.c_str());
  }
  return v;
}

std::vector<double> linearRef(const std::vector<float>& x, const std::vector<float>& w, const std::vector<float>& bias,
                              int64_t B, int64_t M, int64_t N, int64_t K, bool batchedW, Activation act) {
  std::vector<double> y(size_t(B * M * N));
  for (int64_t b = 0; b < B; ++b)
    for (int64_t m = 0; m < M; ++m)
      for (int64_t n = 0; n < N; ++n) {
        const float* xr = &x[(b * M + m) * K];
        const float* wr = &w[((batchedW ? b * N : 0) + n) * K];
        double s = bias.empty() ? 0.0 : bias[n];
        for (int64_t k = 0; k < K; ++k) s += double(xr[k]) * wr[k];
        y[(b * M + m) * N + n] = activateRef(s, act);
      }
  return y;
}

std::vector<double> prepareQkRef(const std::vector<float>& qkv, int64_t B, int64_t N, int heads, int dh,
                                 const std::vector<float>& weight, double eps, const std::vector<float>& sines,
                                 const std::vector<float>& cosines, int64_t prefix) {
  const int64_t D = int64_t(heads) * dh, C = 3 * D;
  std::vector<double> out(qkv.begin(), qkv.end());
  for (int64_t row = 0; row < B * N; ++row)
    for (int64_t h = 0; h < 2 * heads; ++h) {
      double* x = &out[size_t(row * C + h * dh)];
      if (!weight.empty()) {
        double ss = 0;
        for (int64_t d = 0; d < dh; ++d) ss += x[d] * x[d];
        const double ms = ss / dh + eps, r = ms > 0 ? 1.0 / std::sqrt(ms) : 0.0;
        for (int64_t d = 0; d < dh; ++d) x[d] *= r * weight[size_t((h >= heads ? dh : 0) + d)];
      }
      const int64_t t = row % N;
      if (sines.empty() || t < prefix) continue;
      const size_t at = size_t((t - prefix) * dh);
      for (int64_t j = 0; j < dh / 2; ++j) {
        const double a = x[j], b = x[j + dh / 2];
        x[j] = a * cosines[at + j] - b * sines[at + j];
        x[j + dh / 2] = b * cosines[at + j + dh / 2] + a * sines[at + j + dh / 2];
      }
    }
  return out;
}

std::vector<double> attentionRef(const std::vector<float>& q, int64_t qCols, int64_t qOff, const std::vector<float>& k,
                                 int64_t kCols, int64_t kOff, const std::vector<float>& v, int64_t vCols, int64_t vOff,
                                 int64_t B, int64_t Nq, int64_t Nk, int heads, int dh, bool causal, double scale) {
  std::vector<double> out(B * Nq * heads * dh);
  std::vector<double> s(Nk);
  for (int64_t b = 0; b < B; ++b)
    for (int h = 0; h < heads; ++h)
      for (int64_t i = 0; i < Nq; ++i) {
        double mx = -INFINITY;
        for (int64_t j = 0; j < Nk; ++j) {
          if (causal && j > i) { s[j] = -INFINITY; continue; }
          double d = 0;
          for (int c = 0; c < dh; ++c)
            d += double(q[(b * Nq + i) * qCols + qOff + h * dh + c]) * k[(b * Nk + j) * kCols + kOff + h * dh + c];
          s[j] = d * scale;
          mx = std::max(mx, s[j]);
        }
        double sum = 0;
        for (int64_t j = 0; j < Nk; ++j) sum += (s[j] = s[j] == -INFINITY ? 0.0 : std::exp(s[j] - mx));
        for (int c = 0; c < dh; ++c) {
          double acc = 0;
          for (int64_t j = 0; j < Nk; ++j) acc += s[j] * v[(b * Nk + j) * vCols + vOff + h * dh + c];
          out[((b * Nq + i) * heads + h) * dh + c] = acc / sum;
        }
      }
  return out;
}

}  // namespace spar::test
