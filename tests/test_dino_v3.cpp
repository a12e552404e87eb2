// model/dino_v3 (the DINOv3 backbone on the engine, fp32) against the PyTorch reference
// (reference/spar_reference/dino_v3.py) run in float64 with the tiny checkpoint's weights:
// the spar_goldens fixture's "dino" golden of five 128x128 frames, and extra cases made at
// once per build within that fixture by tests/python/make_dino_golden.py (constant black and white images, a
// non-square image whose patch rows and columns differ).
#include <chrono>
#include <filesystem>
#include <functional>
#include <memory>
#include <system_error>

#include "model/dino_v3.h"
#include "model/packed_model.h"
#include "model/spar_config.h"
#include "model/weight_set.h"
#include "tests/golden_support.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

// make_dino_golden.py's cases (fixture spar_goldens: dino/, made once per build).
std::string dinoGoldenDir() { return goldenPath("dino"); }

class DinoV3Test : public EngineTest {
 protected:
  void SetUp() override {
    EngineTest::SetUp();
    model_ = std::make_unique<PackedModel>(PackedModel::open(tinyModelPath()));
    config_ = SparConfig::fromJson(model_->config(), tinyModelPath()).dino;
    weights_ = std::make_unique<WeightSet>(eng(), *model_);
  }
  void TearDown() override {
    weights_.reset();
    model_.reset();
    EngineTest::TearDown();
  }

  // Tokens [V, n, E] of images [V, 3, H, W]; wallMs / gpuMs: host time of the recorded
  // forward's run() and the sum of its dispatches' timestamps.
  std::vector<float> run(DinoV3& dino, const std::vector<float>& images, const Shape& shape, double* wallMs = nullptr,
                         double* gpuMs = nullptr) {
    const int64_t p = config_.patchSize, n = (shape[2] / p) * (shape[3] / p);
    const Tensor in = eng().fromFloats(shape, images);
    GuardedOutput out(eng(), {shape[0], n, config_.embedDim});
    Recorder rec(eng(), /*profile=*/true);
    dino.forward(rec, in, out.tensor(), ws_);
    const auto t0 = std::chrono::steady_clock::now();
    rec.run();
    if (wallMs) *wallMs = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    if (gpuMs) *gpuMs = rec.totalMs();
    dispatches_ = rec.timings().size();
    out.expectAllWritten();
    return out.read();
  }

  std::unique_ptr<PackedModel> model_;
  std::unique_ptr<WeightSet> weights_;
  DinoConfig config_;
  TransformerWorkspace ws_;
  size_t dispatches_ = 0;  // of the last run()
};

// Thresholds. fp32 engine against the float64 reference on the same fp32 inputs, 2 blocks with
// perturbed weights, tokens of unit scale after the final LayerNorm. Measured on lavapipe:
// NMSE 2.2e-13 .. 3.2e-13, max abs 2.2e-6 .. 3.5e-6 (printed by expectClose). PyTorch's own
// float32 forward of the same weights on the "interleaved" frames gives 2.4e-13 / 3.0e-6 against
// the same golden: the error is that of fp32 arithmetic (K = 768 patch-embedding sums), not of
// the engine. Thresholds 2e-12 and 2e-5 (about 6x margin). What mistakes give, measured with
// the reference: RoPE grid transposed 1.2e-2, RoPE halves laid out [rows rows cols cols] 8e-3,
// block 1's proj bias dropped 1.2e-2, final LayerNorm eps 1e-6 instead of 1e-5 8.7e-12.
constexpr double kMaxNmse = 2e-12, kMaxAbs = 2e-5;

// The five frames of the spar_goldens "interleaved" case (the pipeline's prepared images).
TEST_F(DinoV3Test, MatchesReferenceOnFrames) {
  const GoldenCase golden("interleaved");
  const NpyArray images = golden.array("images");
  ASSERT_EQ(images.shape.size(), 4u);
  const int64_t V = images.shape[0], H = images.shape[2], W = images.shape[3];
  const NpyArray expected = golden.array("dino");
  ASSERT_EQ(expected.shape, (std::vector<int64_t>{1, V, (H / 16) * (W / 16), config_.embedDim}));

  DinoV3 dino(eng(), *weights_, config_);
  double firstMs = 0, secondMs = 0, secondGpuMs = 0;
  const std::vector<float> tokens = run(dino, images.toFloats(), {V, 3, H, W}, &firstMs);
  expectClose(tokens, expected.toDoubles(), kMaxNmse, kMaxAbs, "dino interleaved");

  // A second call of the same size allocates nothing and gives the same bits.
  const uint64_t bytes = eng().memory().bytesInUse();
  const std::vector<float> again = run(dino, images.toFloats(), {V, 3, H, W}, &secondMs, &secondGpuMs);
  EXPECT_EQ(again, tokens);
  EXPECT_EQ(ws_.allocations(), 1);
  // The input and guarded output of run() are allocated and freed by the test itself.
  EXPECT_EQ(eng().memory().bytesInUse(), bytes);
  std::printf("    DINOv3 tiny forward, %lld views %lldx%lld: first run %.1f ms wall (with pipeline JIT), "
              "second %.1f ms wall, %.1f ms GPU (%zu dispatches)\n",
              static_cast<long long>(V), static_cast<long long>(H), static_cast<long long>(W), firstMs, secondMs,
              secondGpuMs, dispatches_);
}

// Constant images: every patch embeds to the same token, so only RoPE and the prefix tokens
// tell tokens apart; white (1.0) minus the mean is the largest input the normalization gives.
TEST_F(DinoV3Test, BlackAndWhiteImages) {
  const std::string d = dinoGoldenDir() + "/black_white";
  const NpyArray images = readNpy(d + "/images.npy", {2, 3, 128, 128});
  const NpyArray expected = readNpy(d + "/dino.npy", {2, 64, config_.embedDim});
  DinoV3 dino(eng(), *weights_, config_);
  expectClose(run(dino, images.toFloats(), images.shape), expected.toDoubles(), kMaxNmse, kMaxAbs, "black, white");
}

// 80x112: a 5x7 patch grid, so rows and columns of the RoPE coordinates differ; the same
// DinoV3 then serves a second size (its own buffers and RoPE tables).
TEST_F(DinoV3Test, NonSquareImagesAndSizeChanges) {
  const std::string d = dinoGoldenDir() + "/nonsquare";
  const NpyArray images = readNpy(d + "/images.npy", {2, 3, 80, 112});
  const NpyArray expected = readNpy(d + "/dino.npy", {2, 35, config_.embedDim});
  const std::string bw = dinoGoldenDir() + "/black_white";
  const NpyArray images2 = readNpy(bw + "/images.npy", {2, 3, 128, 128});
  const NpyArray expected2 = readNpy(bw + "/dino.npy", {2, 64, config_.embedDim});
  DinoV3 dino(eng(), *weights_, config_);
  expectClose(run(dino, images.toFloats(), images.shape), expected.toDoubles(), kMaxNmse, kMaxAbs, "80x112");
  expectClose(run(dino, images2.toFloats(), images2.shape), expected2.toDoubles(), kMaxNmse, kMaxAbs, "then 128x128");
  expectClose(run(dino, images.toFloats(), images.shape), expected.toDoubles(), kMaxNmse, kMaxAbs, "80x112 again");
}

std::string errorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST_F(DinoV3Test, RejectsImageSizeNotMultipleOfPatch) {
  DinoV3 dino(eng(), *weights_, config_);
  for (const Shape& shape : {Shape{1, 3, 120, 128}, Shape{2, 3, 128, 40}, Shape{1, 3, 8, 8}}) {
    const Tensor images = eng().tensor(shape), tokens = eng().tensor({shape[0], 64, config_.embedDim});
    Recorder rec(eng());
    const std::string msg = errorOf([&] { dino.forward(rec, images, tokens, ws_); });
    EXPECT_NE(msg.find("is not a positive multiple of the patch size 16"), std::string::npos) << msg;
    EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
  }
}

// A configuration that does not fit the file names the tensor in one line.
TEST_F(DinoV3Test, WeightErrorsNameTheTensor) {
  DinoConfig deeper = config_;
  deeper.depth = config_.depth + 1;
  std::string msg = errorOf([&] { DinoV3(eng(), *weights_, deeper); });
  EXPECT_NE(msg.find("dino.blocks." + std::to_string(config_.depth) + ".norm1.weight"), std::string::npos) << msg;
  EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;

  DinoConfig wider = config_;
  wider.ffnRatio = 2.0;
  msg = errorOf([&] { DinoV3(eng(), *weights_, wider); });
  EXPECT_NE(msg.find("dino.blocks.0.mlp.fc1.weight"), std::string::npos) << msg;
  EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
}

}  // namespace
}  // namespace spar::test
