// model/transformer_block against the PyTorch reference Block (reference/spar_reference/
// transformer.py) run in float64: tests/python/make_block_golden.py writes two perturbed blocks,
// an input and the float64 output as .npy; the engine runs the same two blocks in fp32.
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>

#include "engine/ops/attention.h"
#include "engine/ops/row_padding.h"
#include "formats/npy.h"
#include "model/transformer_block.h"
#include "tests/golden_support.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;

constexpr int64_t kD = 64, kHeadDim = 32, kN = 37, kB = 2, kLayers = 2;

// make_block_golden.py's case (fixture op_goldens, every case made once per build).
std::string goldenDir(const std::string& caseName) { return opGoldenPath("block/" + caseName); }

// Weights straight from the golden directory: <dir>/<key>.npy, uploaded as f32, or with
// fp16Matrices the tensors of 2 dimensions as f16 (as spar-convert --fp16 stores them).
WeightLookup npyWeights(Engine& engine, const std::string& dir, bool fp16Matrices) {
  return [&engine, dir, fp16Matrices](const std::string& key) -> Tensor {
    const fs::path p = fs::path(dir) / (key + ".npy");
    if (!fs::exists(p)) return Tensor();
    const NpyArray a = readNpy(p.string());
    const DType t = fp16Matrices && a.shape.size() >= 2 ? DType::F16 : DType::F32;
    return engine.fromFloats(a.shape, a.toFloats(), t);
  };
}

std::vector<std::string> readLines(const std::string& path) {
  std::ifstream in(path);
  std::vector<std::string> lines;
  for (std::string s; std::getline(in, s);)
    if (!s.empty()) lines.push_back(s);
  return lines;
}

struct BlockCase {
  std::string name;
  TransformerBlockOptions options;
  bool fp16Matrices = false;  // weight matrices stored f16 (their values are fp16 in the golden too)
};
void PrintTo(const BlockCase& c, std::ostream* os) { *os << c.name; }

class TransformerBlockTest : public EngineTest, public ::testing::WithParamInterface<BlockCase> {};

// Two stacked blocks, B=2 sequences of N=37 tokens, D=64 in 2 heads of 32, fp32 on the engine
// against float64 (parameters and input are fp32 values in both; in spar_f16w the weight
// matrices are f16 tensors holding exactly the golden's fp16-rounded values). Measured on
// lavapipe: NMSE 1.8e-14 and max abs 2e-6 in every case. A LayerNorm or QK-norm eps of 1e-6
// instead of 1e-5 already gives 3e-12, so the threshold is 5e-13 (27x the measured error, 6x
// below that mistake) and max abs 1e-5.
TEST_P(TransformerBlockTest, TwoBlocksMatchFloat64Reference) {
  const BlockCase c = GetParam();
  if (c.fp16Matrices && !eng().caps().supportsFp16Storage()) GTEST_SKIP() << "device without fp16 storage";
  const std::string dir = goldenDir(c.name);

  // The reference's state_dict keys are exactly the ones the options ask for.
  const auto keys = readLines(dir + "/keys.txt");
  const auto names = TransformerBlock::weightNames(c.options);
  EXPECT_EQ(std::set<std::string>(keys.begin(), keys.end()), std::set<std::string>(names.begin(), names.end()));

  const WeightLookup weights = npyWeights(eng(), dir, c.fp16Matrices);
  std::vector<TransformerBlock> blocks;
  for (int i = 0; i < kLayers; ++i)
    blocks.emplace_back(eng(), c.options, weights, "blocks." + std::to_string(i));

  const NpyArray x = readNpy(dir + "/x.npy", {kB, kN, kD});
  const NpyArray y = readNpy(dir + "/y.npy", {kB, kN, kD});
  ASSERT_EQ(x.type, NpyType::F32);
  ASSERT_EQ(y.type, NpyType::F64);
  Tensor tx = eng().fromFloats({kB, kN, kD}, x.toFloats());

  TransformerWorkspace ws;
  ws.reserve(eng(), kB * kN, c.options);
  Recorder rec(eng());
  forwardBlocks(rec, blocks, tx, ws);
  rec.run();
  EXPECT_EQ(ws.allocations(), 1);
  expectClose(eng().download(tx), y.toDoubles(), 5e-13, 1e-5, c.name + " 2 blocks");
}

INSTANTIATE_TEST_SUITE_P(Stacks, TransformerBlockTest,
                         ::testing::Values(BlockCase{"spar", TransformerBlockOptions::spar(kD, kHeadDim)},
                                           BlockCase{"clip", TransformerBlockOptions::clipText(kD, kHeadDim)},
                                           BlockCase{"dinov3", TransformerBlockOptions::dinov3(kD, kHeadDim)},
                                           BlockCase{"spar_f16w", TransformerBlockOptions::spar(kD, kHeadDim), true}),
                         [](const auto& info) { return info.param.name; });

// One workspace serves several stacks and sequence lengths: it grows only when asked for more.
TEST_F(EngineTest, TransformerWorkspaceAllocatesOnce) {
  TransformerWorkspace ws;
  ws.reserve(eng(), 2 * 1280, 768, 3072);
  const size_t bytes = ws.bytes();
  // the hidden row as this device's blocks lay it out (engine/ops/row_padding.h)
  EXPECT_EQ(bytes, size_t(2 * 1280) * (768 + 768 + ops::unaliasedRow(eng().plan(), 3072)) * 4);
  ws.reserve(eng(), 2 * 512, 768, 3072);
  ws.reserve(eng(), 1280, 512, 2048);
  EXPECT_EQ(ws.allocations(), 1);
  EXPECT_EQ(ws.bytes(), bytes);
  EXPECT_EQ(ws.qkv(2, 1280, 768).shape(), (Shape{2, 1280, 3 * 768}));
  EXPECT_THROW(ws.hidden(3, 1280, 3072), Error);
  ws.reserve(eng(), 3 * 1280, 768, 3072);
  EXPECT_EQ(ws.allocations(), 2);
}

// Where the plan pads aliased rows (engine/ops/row_padding.h) and the lookup can pad, the MLP's
// hidden row is 4 wider: mlp.0 with zero rows (and bias entries), mlp.2 with zero columns. The
// sums are the same ones plus exact zeros, so the output equals the unpadded block's bit for bit.
// D 128 and a hidden of 512 (2048-byte rows), with biases (clip, dinov3: LayerScale too) and
// without (spar); the plan forced both ways on whatever device runs the test.
TEST_F(EngineTest, MlpHiddenRowsPaddedGiveTheSameBlock) {
  constexpr int64_t D = 128, H = 512, N = 37;
  for (const auto& options : {TransformerBlockOptions::spar(D, kHeadDim), TransformerBlockOptions::clipText(D, kHeadDim),
                              TransformerBlockOptions::dinov3(D, kHeadDim)}) {
    std::map<std::string, std::vector<float>> values;
    std::map<std::string, Shape> shapes;
    uint32_t seed = 70;
    for (const auto& n : TransformerBlock::weightNames(options)) {
      const bool norm = n.find("norm") != std::string::npos;
      const Shape s = n == "attn.to_qkv.weight"   ? Shape{3 * D, D}
                      : n == "attn.to_qkv.bias"   ? Shape{3 * D}
                      : n == "attn.fc.weight"     ? Shape{D, D}
                      : n == "attn.fc.bias"       ? Shape{D}
                      : n == "mlp.mlp.0.weight"   ? Shape{H, D}
                      : n == "mlp.mlp.0.bias"     ? Shape{H}
                      : n == "mlp.mlp.2.weight"   ? Shape{D, H}
                      : n.find("_norm") != std::string::npos ? Shape{kHeadDim}
                                                             : Shape{D};
      shapes[n] = s;
      values[n] = norm ? randomUniform(shapeNumel(s), 0.5f, 1.5f, seed++) : randomUniform(shapeNumel(s), -0.1f, 0.1f, seed++);
    }
    int paddedAsks = 0;
    WeightLookup lookup = [&](const std::string& k) -> Tensor {
      return values.count(k) ? eng().fromFloats(shapes.at(k), values.at(k)) : Tensor();
    };
    // zeros appended to the last dimension, or rows of zeros (what WeightSet::requirePadded does)
    lookup.padded = [&](const std::string& k, const Shape& padded) -> Tensor {
      ++paddedAsks;
      const Shape& s = shapes.at(k);
      std::vector<float> v(size_t(shapeNumel(padded)), 0.0f);
      const int64_t cols = s.back(), rows = shapeNumel(s) / cols;
      for (int64_t r = 0; r < rows; ++r)
        std::copy_n(values.at(k).begin() + r * cols, cols, v.begin() + r * padded.back());
      return eng().fromFloats(padded, v);
    };
    const std::vector<float> input = randomNormal(N * D, 0, 1, 80);
    auto run = [&](bool pad) {
      KernelTuning t = eng().options().tuning;
      t.kernels = "cpu";  // the CPU family also in a program's GPU-family run
      t.padAliasedRows = pad;
      eng().setTuning(t);
      paddedAsks = 0;
      const TransformerBlock block(eng(), options, lookup);
      EXPECT_EQ(block.hiddenRow(), pad ? H + ops::kRowPadding : H);
      EXPECT_EQ(paddedAsks, pad ? (options.mlpBias ? 3 : 2) : 0);
      Tensor x = eng().fromFloats({1, N, D}, input);
      TransformerWorkspace ws;
      ws.reserve(eng(), N, options);
      Recorder rec(eng());
      block.forward(rec, x, ws);
      rec.run();
      return eng().download(x);
    };
    const KernelTuning saved = eng().options().tuning;
    const std::vector<float> plain = run(false), padded = run(true);
    eng().setTuning(saved);
    ASSERT_EQ(plain.size(), padded.size());
    EXPECT_EQ(plain, padded) << (options.layerScale ? "dinov3" : options.mlpBias ? "clip" : "spar");
    for (float v : padded) ASSERT_TRUE(std::isfinite(v));
    // A lookup that cannot pad (no `padded`) gets the block as stored, whatever the plan.
    WeightLookup plainLookup = lookup.find;
    KernelTuning t = saved;
    t.kernels = "cpu";
    t.padAliasedRows = true;
    eng().setTuning(t);
    EXPECT_EQ(TransformerBlock(eng(), options, plainLookup).hiddenRow(), H);
    eng().setTuning(saved);
  }
}

// A block is at most 7 dispatches (the GPU-speed bar), with the q / k norm and with RoPE: the
// norm and the rotation happen inside the attention kernel (engine/ops/attention.h, QkPrep;
// where the device's kernel cannot, SwiftShader's, they are one dispatch each before it).
// RoPE changes the block's output (the tables reach the kernel); that it rotates exactly as
// rope() would: test_attention's AttentionPreparesQAndKAsTheOpsWould.
TEST_F(EngineTest, TransformerBlockIsSevenDispatchesWithNormAndRope) {
  const auto opts = TransformerBlockOptions::spar(kD, kHeadDim);
  std::map<std::string, Tensor> w;
  uint32_t seed = 50;
  auto lookup = [&](const std::string& k) -> Tensor {
    if (!w.count(k)) {
      const bool norm = k.find("norm") != std::string::npos;
      const int64_t d = k.find("_norm") != std::string::npos ? kHeadDim : kD;
      const Shape s = k == "attn.to_qkv.weight" ? Shape{3 * kD, kD}
                      : k == "attn.fc.weight"   ? Shape{kD, kD}
                      : k == "mlp.mlp.0.weight" ? Shape{4 * kD, kD}
                      : k == "mlp.mlp.2.weight" ? Shape{kD, 4 * kD}
                                                : Shape{d};
      w[k] = eng().fromFloats(s, norm ? randomUniform(shapeNumel(s), 0.5f, 1.5f, seed++)
                                      : randomUniform(shapeNumel(s), -0.1f, 0.1f, seed++));
    }
    return w.at(k);
  };
  const TransformerBlock block(eng(), opts, lookup);
  const std::vector<float> x0 = randomNormal(kB * kN * kD, 0, 1, 60);
  const int64_t prefix = 2;
  std::vector<float> angles = randomUniform((kN - prefix) * kHeadDim, -3, 3, 61), sines, cosines;
  for (float a : angles) sines.push_back(std::sin(a)), cosines.push_back(std::cos(a));
  const BlockRope rope{eng().fromFloats({kN - prefix, kHeadDim}, sines), eng().fromFloats({kN - prefix, kHeadDim}, cosines),
                       prefix};
  TransformerWorkspace ws;
  ws.reserve(eng(), kB * kN, opts);
  auto run = [&](const BlockRope* r) {
    const Tensor x = eng().fromFloats({kB, kN, kD}, x0);
    Recorder rec(eng());
    rec.setStage("blocks");
    block.forward(rec, x, ws, r);
    rec.run();
    const StageCounts c = rec.lastRunCounts().at("blocks");
    EXPECT_EQ(c.transformerBlocks, 1u);
    QkPrep prep;  // what the block asks attention for
    prep.normWeight = eng().tensor({2, kHeadDim});
    if (r) prep.ropeSin = r->sin;
    const uint64_t apart = preparesInKernel(eng(), int(kHeadDim), prep) ? 0 : (r ? 2 : 1);
    EXPECT_LE(c.blockDispatches, 7u + apart) << (r ? "with RoPE" : "without RoPE");
    EXPECT_EQ(c.blockDispatches, c.dispatches);
    return eng().download(x);
  };
  const std::vector<float> plain = run(nullptr), rotated = run(&rope);
  double changed = 0;
  for (size_t i = 0; i < plain.size(); ++i) {
    ASSERT_TRUE(std::isfinite(rotated[i]));
    changed = std::max(changed, double(std::abs(plain[i] - rotated[i])));
  }
  EXPECT_GT(changed, 1e-3);
}

// Missing and misshapen weights are reported with their full key.
TEST_F(EngineTest, TransformerBlockReportsBadWeights) {
  const auto opts = TransformerBlockOptions::spar(kD, kHeadDim);
  std::map<std::string, Tensor> w;
  for (const auto& n : TransformerBlock::weightNames(opts)) {
    Shape s = n == "attn.to_qkv.weight" ? Shape{3 * kD, kD}
              : n == "attn.fc.weight"   ? Shape{kD, kD}
              : n == "mlp.mlp.0.weight" ? Shape{4 * kD, kD}
              : n == "mlp.mlp.2.weight" ? Shape{kD, 4 * kD}
              : n.find("_norm") != std::string::npos ? Shape{kHeadDim}
                                                     : Shape{kD};
    w["enc.0." + n] = eng().tensor(s);
  }
  auto lookup = [&](const std::string& k) { return w.count(k) ? w.at(k) : Tensor(); };
  EXPECT_NO_THROW(TransformerBlock(eng(), opts, lookup, "enc.0."));
  EXPECT_NO_THROW(TransformerBlock(eng(), opts, lookup, "enc.0"));
  try {
    TransformerBlock(eng(), opts, lookup, "enc.1");
    ADD_FAILURE() << "no error for a missing prefix";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("missing weight enc.1.norm1.weight"), std::string::npos) << e.what();
  }
  w["enc.0.attn.fc.weight"] = eng().tensor({kD, kD + 1});
  try {
    TransformerBlock(eng(), opts, lookup, "enc.0");
    ADD_FAILURE() << "no error for a misshapen weight";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("enc.0.attn.fc.weight is f32[64, 65]"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace spar::test
