// Shared by tests/test_bpe_tokenizer.cpp and tests/test_clip_text.cpp: a fixed list of prompts
// that exercises every rule of converter/spar_reference/bpe.py, and the reference's goldens of
// them made once per test process by tests/python/make_text_golden.py (into a directory of the
// process's own, removed when it ends).
#pragma once
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <system_error>
#include <vector>

#include <nlohmann/json.hpp>
#include <unistd.h>

#include "engine/error.h"
#include "tests/golden_support.h"

namespace spar::test {

inline const std::vector<std::string>& textPrompts() {
  static const std::vector<std::string> prompts = {
      "",
      "a photo of a cat",
      "   Leading and trailing spaces   ",
      "Mixed CASE Words HeLLo",
      "don't you're we've I'm they'll he'd it's 'S 'RE",
      "numbers 12345 and 3.14159, 1st 2nd \u00bd \u2167 \u0663\u0664",
      "punctuation!!! ...?? (brackets) [x] {y} <z> @#$%^&* -- a-b_c",
      "\u00fcn\u00efc\u00f6d\u00e9 ch\u00e4ir caf\u00e9 na\u00efve r\u00e9sum\u00e9 \u0142\u00f3d\u017a",
      "cafe\u0301 (combining accent, NFC)",
      "\u732b\u3068\u72ac \u4e2d\u6587\u6d4b\u8bd5 \ud55c\uad6d\uc5b4",
      "\U0001F431\U0001F436 \U0001F44D\U0001F3FD family \U0001F468\u200D\U0001F469\u200D\U0001F467!",
      "tab\tnew\nline\r\n  many   spaces\u3000ideographic\u00a0nbsp\u2003em\u2028sep",
      "fish &amp; chips &lt;b&gt; &#39;q&#39; &#x263A; &notit; &amp;amp; &copy2026 &#0; &#150; &#xD800; &bogus; & x",
      "\uff26\uff35\uff2c\uff2c\u3000\uff57\uff49\uff44\uff54\uff48 \ufb01ne \ufb02ow \u0132ssel \u01c4",
      "\u201csmart\u201d \u2018quotes\u2019 and\u2019s",
      "\x07" "bell \x1b[31mred\x1b[0m zero\u200bwidth soft\u00adhyphen \ufeffbom",
      "\u039f\u0394\u039f\u03a3 \u03a3\u038a\u03a3\u03a5\u03a6\u039f\u03a3 \u0130stanbul STRASSE \u1e9e",
      "<|startoftext|>hello<|endoftext|> world",
      "a " + [] {
        std::string s;
        for (int i = 0; i < 90; ++i) s += "very ";
        return s;
      }() + "long prompt that CLIP truncates at 77 tokens",
      [] {  // 75 tokens: exactly 77 with start and end
        std::string s;
        for (int i = 0; i < 75; ++i) s += "x ";
        return s;
      }(),
      [] {  // 76 tokens: one too many
        std::string s;
        for (int i = 0; i < 76; ++i) s += "x ";
        return s;
      }(),
      "supercalifragilisticexpialidocious antidisestablishmentarianism",
      "   ",
  };
  return prompts;
}

// A directory of the process's own under the tests' scratch directory, removed when it ends,
// filled by make_text_golden.py with `args` (besides --bpe and --out).
struct TextGoldenDir {
  std::string path;
  TextGoldenDir(const std::string& name, const std::string& args) {
    namespace fs = std::filesystem;
    const fs::path d = fs::path(SPAR_TEST_OUT_DIR) / (name + "_" + std::to_string(::getpid()));
    fs::remove_all(d);
    fs::create_directories(d);
    path = d.string();
    const std::string cmd = std::string("\"") + SPAR_PYTHON + "\" \"" + SPAR_SOURCE_DIR +
                            "/tests/python/make_text_golden.py\" --bpe \"" + clipBpePath() + "\" --out \"" + path +
                            "\" " + args;
    const int rc = std::system(cmd.c_str());
    if (rc != 0) throw Error("golden maker failed (" + std::to_string(rc) + "): " + cmd);
  }
  ~TextGoldenDir() {
    std::error_code ec;
    std::filesystem::remove_all(path, ec);
  }
};

inline std::string writePromptsFile() {
  const std::string file = std::string(SPAR_TEST_OUT_DIR) + "/text_prompts_" + std::to_string(::getpid()) + ".json";
  std::ofstream f(file, std::ios::binary);
  f << nlohmann::json(textPrompts()).dump();
  return file;
}

// The goldens of textPrompts() (made on first use; with embeddings.npy when asked for).
inline const std::string& textGoldenDir(bool embeddings) {
  static const std::string prompts = writePromptsFile();
  static const TextGoldenDir dir(
      "text_golden", "--prompts \"" + prompts + "\"" +
                         (embeddings ? " --checkpoint \"" + semanticGoldenPath("tiny_semantic.pt") + "\" --config \"" +
                                           semanticGoldenPath("tiny_semantic.json") + "\""
                                     : std::string()));
  std::filesystem::remove(prompts);
  return dir.path;
}

// n random prompts of make_text_golden.py's random_prompts (DIR/prompts.json) and their ids.
inline const std::string& randomTextGoldenDir(int n, int seed) {
  static const TextGoldenDir dir("text_golden_random",
                                 "--random " + std::to_string(n) + " --seed " + std::to_string(seed));
  return dir.path;
}

}  // namespace spar::test
