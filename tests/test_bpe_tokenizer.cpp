// model/bpe_tokenizer (CLIP's BPE tokenizer in C++) against reference/spar_reference/bpe.py:
// the ids of a fixed list of prompts (tests/text_golden.h: empty, > 77 tokens, exactly 77,
// non-ASCII, CJK, emoji, punctuation, numbers, mixed case, whitespace runs, HTML references,
// ligatures, full-width forms, controls, special tokens) must be identical, and the table packed
// in the semantic fixture's model must give the same tokenizer as the file. Skips when the
// merges table is not on this machine.
#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>

#include <nlohmann/json.hpp>

#include "text/bpe_tokenizer.h"
#include "formats/npy.h"
#include "model/packed_model.h"
#include "tests/golden_support.h"
#include "tests/text_golden.h"

namespace spar::test {
namespace {

class BpeTokenizerTest : public ::testing::Test {
 protected:
  static const BpeTokenizer& tokenizer() {
    static const BpeTokenizer t = BpeTokenizer::fromFile(clipBpePath());
    return t;
  }
};

TEST_F(BpeTokenizerTest, VocabularyAndSpecialTokens) {
  EXPECT_EQ(tokenizer().vocabSize(), 49408);
  EXPECT_EQ(tokenizer().sot(), 49406);
  EXPECT_EQ(tokenizer().eot(), 49407);
}

TEST_F(BpeTokenizerTest, MatchesReferenceIds) {
  const std::string dir = textGoldenDir();
  const std::vector<std::string>& prompts = textPrompts();
  const int64_t P = static_cast<int64_t>(prompts.size()), L = BpeTokenizer::kContextLength;
  const std::vector<int64_t> want = readNpy(dir + "/tokens.npy", {P, L}).toInt64s();
  std::ifstream f(dir + "/text.json");
  const nlohmann::json detail = nlohmann::json::parse(f);
  const std::vector<int32_t> got = tokenizer().tokenize(prompts);
  ASSERT_EQ(got.size(), static_cast<size_t>(P * L));
  int mismatched = 0;
  for (int64_t p = 0; p < P; ++p) {
    const std::string& prompt = prompts[size_t(p)];
    EXPECT_EQ(BpeTokenizer::normalize(prompt), detail[p]["normalized"].get<std::string>()) << "prompt " << p;
    EXPECT_EQ(BpeTokenizer::preTokenize(BpeTokenizer::normalize(prompt)),
              detail[p]["pieces"].get<std::vector<std::string>>())
        << "prompt " << p;
    const std::vector<int32_t> enc = tokenizer().encode(prompt);
    EXPECT_EQ(std::vector<int64_t>(enc.begin(), enc.end()), detail[p]["encoded"].get<std::vector<int64_t>>())
        << "prompt " << p << ": " << prompt;
    bool same = true;
    for (int64_t j = 0; j < L; ++j) same = same && got[size_t(p * L + j)] == want[size_t(p * L + j)];
    if (!same) ++mismatched;
    EXPECT_TRUE(same) << "prompt " << p << " '" << prompt << "' tokenizes differently";
  }
  std::printf("BPE: %lld prompts, %d differ from bpe.py\n", static_cast<long long>(P), mismatched);
}

// 4000 random prompts (make_text_golden.py random_prompts: the tricky pieces of every rule,
// and random code points of every plane, some assigned after the reference's Unicode version).
TEST_F(BpeTokenizerTest, RandomPromptsMatchReference) {
  const std::string dir = randomTextGoldenDir();
  std::ifstream pf(dir + "/prompts.json");
  const std::vector<std::string> prompts = nlohmann::json::parse(pf).get<std::vector<std::string>>();
  std::ifstream tf(dir + "/text.json");
  const nlohmann::json detail = nlohmann::json::parse(tf);
  const int64_t P = static_cast<int64_t>(prompts.size()), L = BpeTokenizer::kContextLength;
  const std::vector<int64_t> want = readNpy(dir + "/tokens.npy", {P, L}).toInt64s();
  const std::vector<int32_t> got = tokenizer().tokenize(prompts);
  int differ = 0;
  for (int64_t p = 0; p < P; ++p) {
    const std::vector<int32_t> enc = tokenizer().encode(prompts[size_t(p)]);
    const bool same = std::equal(got.begin() + p * L, got.begin() + (p + 1) * L, want.begin() + p * L) &&
                      std::vector<int64_t>(enc.begin(), enc.end()) == detail[p]["encoded"].get<std::vector<int64_t>>();
    if (!same && ++differ <= 5)
      ADD_FAILURE() << "random prompt " << p << ": normalized '" << BpeTokenizer::normalize(prompts[size_t(p)])
                    << "', reference '" << detail[p]["normalized"].get<std::string>() << "'";
  }
  EXPECT_EQ(differ, 0);
  std::printf("BPE: %lld random prompts, %d differ from bpe.py\n", static_cast<long long>(P), differ);
}

TEST_F(BpeTokenizerTest, TruncationKeepsEndToken) {
  const std::vector<std::string>& prompts = textPrompts();
  const std::vector<int32_t> ids = tokenizer().tokenize({prompts[18], prompts[19], prompts[20], ""});
  const int L = BpeTokenizer::kContextLength;
  for (int r = 0; r < 3; ++r) {
    EXPECT_EQ(ids[size_t(r * L)], tokenizer().sot());
    EXPECT_EQ(ids[size_t(r * L + L - 1)], tokenizer().eot()) << "row " << r;
  }
  // The empty prompt: start, end, zeros.
  EXPECT_EQ(ids[size_t(3 * L)], tokenizer().sot());
  EXPECT_EQ(ids[size_t(3 * L + 1)], tokenizer().eot());
  for (int j = 2; j < L; ++j) EXPECT_EQ(ids[size_t(3 * L + j)], 0);
  EXPECT_THROW(tokenizer().tokenize({"a"}, 1), Error);
}

// The fixture's goldens (cli.py compute_labels on labels.json) and the packed table.
TEST_F(BpeTokenizerTest, PackedTableMatchesFixtureGoldens) {
  const PackedModel model = PackedModel::open(semanticGoldenPath("tiny_semantic.spar"));
  const BpeTokenizer packed = BpeTokenizer::fromModel(model);
  const GoldenCase golden(semanticGoldenPath("semantic"));
  const std::vector<std::string> labels = golden.manifest().at("labels").get<std::vector<std::string>>();
  const int64_t P = static_cast<int64_t>(labels.size()), L = BpeTokenizer::kContextLength;
  const std::vector<int64_t> want = golden.array("text_tokens").toInt64s();
  ASSERT_EQ(golden.shape("text_tokens"), (std::vector<int64_t>{P, L}));
  const std::vector<int32_t> got = packed.tokenize(labels);
  EXPECT_EQ(std::vector<int64_t>(got.begin(), got.end()), want);
  EXPECT_EQ(got, tokenizer().tokenize(labels));
}

TEST_F(BpeTokenizerTest, RefusesBrokenTables) {
  const std::vector<uint8_t> notGzip = {'h', 'e', 'l', 'l', 'o'};
  EXPECT_THROW(BpeTokenizer{std::span<const uint8_t>(notGzip)}, Error);
  std::ifstream f(clipBpePath(), std::ios::binary);
  std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  bytes.resize(bytes.size() / 2);  // truncated stream
  EXPECT_THROW(BpeTokenizer{std::span<const uint8_t>(bytes)}, Error);
  EXPECT_THROW(BpeTokenizer::fromFile("/nonexistent/bpe.txt.gz"), Error);
}

}  // namespace
}  // namespace spar::test
