// model/clip_text (CLIP's text encoder on the engine, fp32) against the PyTorch reference
// (reference/spar_reference/clip_text.py) in float64 with the semantic fixture's CLIP weights:
// the prompts of tests/text_golden.h (goldens made at test time by make_text_golden.py) and the
// fixture's own labels (semantic/text_embeddings.npy, made by spar-reference goldens --labels).
// Skips when the BPE merges table is not on this machine.
#include <gtest/gtest.h>

#include <memory>

#include "text/bpe_tokenizer.h"
#include "model/clip_text.h"
#include "formats/npy.h"
#include "model/packed_model.h"
#include "model/weight_set.h"
#include "tests/golden_support.h"
#include "tests/test_support.h"
#include "tests/text_golden.h"

namespace spar::test {
namespace {

class ClipTextTest : public EngineTest {
 protected:
  void SetUp() override {
    EngineTest::SetUp();
    const std::string path = semanticGoldenPath("tiny_semantic.spar");
    model_ = std::make_unique<PackedModel>(PackedModel::open(path));
    config_ = ClipTextConfig::fromJson(model_->config().at("clip"), path);
    tokenizer_ = std::make_unique<BpeTokenizer>(BpeTokenizer::fromModel(*model_));
  }
  void TearDown() override {
    weights_.reset();
    model_.reset();
    EngineTest::TearDown();
  }

  // Embeddings [P, E] of the prompts with a weight set of the given matrix precision.
  std::vector<float> embed(const std::vector<std::string>& prompts, DType matrices = DType::F32) {
    weights_ = std::make_unique<WeightSet>(eng(), *model_, matrices);
    ClipTextEncoder enc(eng(), *weights_, config_);
    const std::vector<int32_t> ids = tokenizer_->tokenize(prompts, int(config_.contextLength));
    GuardedOutput out(eng(), {int64_t(prompts.size()), config_.embedDim});
    Recorder rec(eng());
    enc.forward(rec, ids, out.tensor(), ws_);
    rec.run();
    out.expectAllWritten();
    return out.read();
  }

  std::unique_ptr<PackedModel> model_;
  std::unique_ptr<WeightSet> weights_;
  std::unique_ptr<BpeTokenizer> tokenizer_;
  ClipTextConfig config_;
  TransformerWorkspace ws_;
};

TEST_F(ClipTextTest, PromptListMatchesFloat64Reference) {
  const std::string dir = textGoldenDir();
  const int64_t P = int64_t(textPrompts().size());
  const std::vector<double> want = readNpy(dir + "/embeddings.npy", {P, config_.embedDim}).toDoubles();
  expectClose(embed(textPrompts()), want, 1e-10, 1e-5, "CLIP text, " + std::to_string(P) + " prompts");
}

TEST_F(ClipTextTest, FixtureLabelsMatchGoldens) {
  const GoldenCase golden(semanticGoldenPath("semantic"));
  const std::vector<std::string> labels = golden.manifest().at("labels").get<std::vector<std::string>>();
  ASSERT_EQ(golden.shape("text_embeddings"), (std::vector<int64_t>{int64_t(labels.size()), config_.embedDim}));
  expectClose(embed(labels), golden.doubles("text_embeddings"), 1e-10, 1e-5, "CLIP text, fixture labels");
}

// The batch is cut after its last end token: a short prompt alone and next to a 77-token one
// gives the same embedding (to rounding).
TEST_F(ClipTextTest, BatchCompositionDoesNotMatter) {
  const std::vector<std::string>& all = textPrompts();
  const std::vector<float> alone = embed({all[1]});
  const std::vector<float> batch = embed({all[18], all[1]});
  const std::vector<float> second(batch.begin() + config_.embedDim, batch.end());
  expectClose(second, toDouble(alone), 1e-12, 1e-5, "short prompt alone vs in a long batch");
}

// fp16 weight matrices (the --fp16 pack): documented error, not a requirement of equality.
TEST_F(ClipTextTest, Fp16MatricesStayClose) {
  if (!eng().readsFp16Inputs()) GTEST_SKIP() << "device without fp16 inputs";
  const std::string dir = textGoldenDir();
  const int64_t P = int64_t(textPrompts().size());
  const std::vector<double> want = readNpy(dir + "/embeddings.npy", {P, config_.embedDim}).toDoubles();
  expectClose(embed(textPrompts(), DType::F16), want, 1e-5, 1e-2, "CLIP text, fp16 matrices");
}

TEST_F(ClipTextTest, RefusesBadIds) {
  weights_ = std::make_unique<WeightSet>(eng(), *model_);
  ClipTextEncoder enc(eng(), *weights_, config_);
  const Tensor out = eng().tensor({1, config_.embedDim});
  Recorder rec(eng());
  std::vector<int32_t> ids(size_t(config_.contextLength), 0);
  ids[0] = int32_t(config_.vocabSize);
  EXPECT_THROW(enc.forward(rec, ids, out, ws_), Error);
  EXPECT_THROW(enc.forward(rec, std::vector<int32_t>(5, 0), out, ws_), Error);
}

}  // namespace
}  // namespace spar::test
