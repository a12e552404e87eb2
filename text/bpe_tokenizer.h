// CLIP's byte-level BPE tokenizer, reproducing reference/spar_reference/bpe.py id for id
// (which follows openai/CLIP's simple_tokenizer.py, with bpe.py's standard-library stand-in
// for ftfy.fix_text):
//
//   text -> fix_text (terminal escapes and controls removed, ligatures split, full-width
//           folded, curly quotes straightened, CR/CRLF -> LF, NFC)
//        -> html.unescape twice -> strip -> whitespace runs to one space -> lower()
//        -> CLIP's pre-tokenizer (<|startoftext|>, <|endoftext|>, 's 't 're 've 'm 'll 'd,
//           letter runs, single digits, runs of anything else; whitespace separates)
//        -> each piece's UTF-8 bytes as byte symbols -> BPE merges by rank -> ids
//   tokenize: [sot, ids..., eot] padded with 0 to the context length; a longer sequence is cut
//   to the context length with eot put back last (CLIP's truncate=True).
//
// Unicode properties (letters L*, numbers N*, decimal/digit numeric types), lower-casing (full
// case mapping with final sigma, as Python's str.lower) and NFC/NFKC come from ICU, pinned to
// the reference Python's Unicode version (3.11: 14.0; ICU 72 has 15.0): code points assigned
// later count as unassigned, as they do for bpe.py (see kUnicodeMajor in the .cpp). HTML
// character references use the tables of Python's html module (text/html_entities.inc,
// generated).
// Input strings are UTF-8; an invalid byte sequence decodes as U+FFFD.
#pragma once
#include <cstdint>
#include <span>
#include <string>
#include <unordered_map>
#include <vector>

namespace spar {

class PackedModel;

class BpeTokenizer {
 public:
  static constexpr int kContextLength = 77;
  static constexpr int kMerges = 48894;  // lines 1..48894 of the table (line 0 is a header)
  static constexpr const char* kPackedName = "clip.bpe_merges";

  // gzipped: the bytes of bpe_simple_vocab_16e6.txt.gz. Throws spar::Error when they do not
  // inflate or hold fewer than kMerges merge lines.
  explicit BpeTokenizer(std::span<const uint8_t> gzipped);
  static BpeTokenizer fromFile(const std::string& path);
  // The table packed as U8 "clip.bpe_merges" (converter/FORMAT.md); throws when absent.
  static BpeTokenizer fromModel(const PackedModel& model);

  // The BPE ids of one text, without start and end tokens (bpe.py encode).
  std::vector<int32_t> encode(const std::string& text) const;
  // [prompts.size(), contextLength] ids, row-major (bpe.py tokenize with truncate=True).
  std::vector<int32_t> tokenize(const std::vector<std::string>& prompts, int contextLength = kContextLength) const;

  // The text after cleaning and lower-casing, and its pre-tokens (UTF-8), for tests.
  static std::string normalize(const std::string& text);
  static std::vector<std::string> preTokenize(const std::string& normalized);

  int32_t sot() const { return sot_; }
  int32_t eot() const { return eot_; }
  int32_t vocabSize() const { return static_cast<int32_t>(encoder_.size()); }

 private:
  // The merged symbols of one pre-token already mapped to byte symbols (UTF-8 each).
  std::vector<std::string> bpe(const std::vector<std::string>& symbols) const;

  std::string byteSymbol_[256];                        // bytes_to_unicode, as UTF-8
  std::unordered_map<std::string, int32_t> encoder_;   // vocabulary entry -> id
  std::unordered_map<std::string, int32_t> ranks_;     // "first second" -> merge rank
  int32_t sot_ = 0, eot_ = 0;
};

}  // namespace spar
