// Shared by tests/test_bpe_tokenizer.cpp and tests/test_clip_text.cpp: a fixed list of prompts
// that exercises every rule of reference/spar_reference/bpe.py (tests/data/text_prompts.json),
// and the reference's goldens of them, made once per build by tests/python/make_text_golden.py
// within the semantic fixture (make_spar_goldens.py --semantic: text/ and text_random/).
#pragma once
#include <fstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "spar/error.h"
#include "tests/golden_support.h"

namespace spar::test {

// tests/data/text_prompts.json: plain and mixed-case words, contractions, numbers of every
// Unicode category, punctuation, accents (composed and combining), CJK, emoji with modifiers
// and joiners, white space of every kind, HTML references (valid, invalid, unterminated),
// full-width forms and ligatures, terminal escapes and removed controls, special tokens; then,
// at 18-20, 90 "very "s (truncated), 75 tokens (exactly 77 with start and end), 76 tokens (one
// too many); then two long words and white space alone.
inline const std::vector<std::string>& textPrompts() {
  static const std::vector<std::string> prompts = [] {
    const std::string path = std::string(SPAR_SOURCE_DIR) + "/tests/data/text_prompts.json";
    std::ifstream f(path, std::ios::binary);
    if (!f) throw Error(path + ": cannot open");
    return nlohmann::json::parse(f).get<std::vector<std::string>>();
  }();
  return prompts;
}

// The goldens of textPrompts(): tokens.npy, text.json and embeddings.npy (the semantic
// fixture's CLIP text encoder in float64).
inline std::string textGoldenDir() { return semanticGoldenPath("text"); }

// 4000 random prompts of make_text_golden.py's random_prompts (seed 11; DIR/prompts.json) and
// their ids.
inline std::string randomTextGoldenDir() { return semanticGoldenPath("text_random"); }

}  // namespace spar::test
