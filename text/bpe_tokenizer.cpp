#include "text/bpe_tokenizer.h"

#include <unicode/locid.h>
#include <unicode/normalizer2.h>
#include <unicode/uchar.h>
#include <unicode/uniset.h>
#include <unicode/unistr.h>
#include <zlib.h>

#include <algorithm>
#include <array>
#include <fstream>
#include <iterator>
#include <memory>
#include <string_view>

#include "spar/error.h"
#include "model/packed_model.h"

namespace spar {
namespace {

using Text = std::u32string;  // code points: bpe.py works on Python str, i.e. code points

// ------------------------------------------------------------------------------ Unicode (ICU)

Text toText(const icu::UnicodeString& s) {
  Text out;
  out.reserve(static_cast<size_t>(s.length()));
  for (int32_t i = 0; i < s.length(); i = s.moveIndex32(i, 1)) out.push_back(static_cast<char32_t>(s.char32At(i)));
  return out;
}

icu::UnicodeString toIcu(const Text& t) {
  return icu::UnicodeString::fromUTF32(reinterpret_cast<const UChar32*>(t.data()), static_cast<int32_t>(t.size()));
}

Text fromUtf8(const std::string& s) { return toText(icu::UnicodeString::fromUTF8(s)); }

std::string toUtf8(const Text& t) {
  std::string out;
  toIcu(t).toUTF8String(out);
  return out;
}

// The reference's Unicode version: Python 3.11's unicodedata (Debian 12's /usr/bin/python3)
// has 14.0; ICU 72 has 15.0. Code points assigned after it are unassigned (Cn) to the
// reference: not letters or numbers, never normalized (CJK Extension H, Kawi, ... tokenize
// differently otherwise). Raise it with the Python that makes the goldens.
constexpr uint8_t kUnicodeMajor = 14, kUnicodeMinor = 0;

bool assignedInReference(char32_t c) {
  UVersionInfo age;
  u_charAge(static_cast<UChar32>(c), age);
  return age[0] < kUnicodeMajor || (age[0] == kUnicodeMajor && age[1] <= kUnicodeMinor);
}

// ICU's NFC / NFKC restricted to the code points of the reference's Unicode version (ICU's
// own way of running an older version's normalization: a FilteredNormalizer2).
class ReferenceNormalizers {
 public:
  ReferenceNormalizers() {
    UErrorCode status = U_ZERO_ERROR;
    const icu::Normalizer2* nfc = icu::Normalizer2::getNFCInstance(status);
    const icu::Normalizer2* nfkc = icu::Normalizer2::getNFKCInstance(status);
    const std::string pattern = "[:age=" + std::to_string(kUnicodeMajor) + "." + std::to_string(kUnicodeMinor) + ":]";
    set_ = icu::UnicodeSet(icu::UnicodeString::fromUTF8(pattern), status);
    if (U_FAILURE(status) || !nfc || !nfkc)
      throw Error(std::string("BPE tokenizer: ICU normalizer: ") + u_errorName(status));
    set_.freeze();
    nfc_ = std::make_unique<icu::FilteredNormalizer2>(*nfc, set_);
    nfkc_ = std::make_unique<icu::FilteredNormalizer2>(*nfkc, set_);
  }
  const icu::Normalizer2& get(bool compat) const { return compat ? *nfkc_ : *nfc_; }

 private:
  icu::UnicodeSet set_;
  std::unique_ptr<icu::FilteredNormalizer2> nfc_, nfkc_;
};

const icu::Normalizer2& normalizer(bool compat) {
  static const ReferenceNormalizers n;  // thread-safe initialization; ICU normalizers are const-safe
  return n.get(compat);
}

Text normalized(const Text& t, bool compat) {
  UErrorCode status = U_ZERO_ERROR;
  const icu::UnicodeString out = normalizer(compat).normalize(toIcu(t), status);
  if (U_FAILURE(status)) throw Error(std::string("BPE tokenizer: ICU normalize: ") + u_errorName(status));
  return toText(out);
}

bool isLetter(char32_t c) {
  return (U_GET_GC_MASK(static_cast<UChar32>(c)) & U_GC_L_MASK) != 0 && assignedInReference(c);
}
bool isNumber(char32_t c) {
  return (U_GET_GC_MASK(static_cast<UChar32>(c)) & U_GC_N_MASK) != 0 && assignedInReference(c);
}
// Python's str.isdigit: numeric type Decimal or Digit.
bool isPyDigit(char32_t c) {
  const int t = u_getIntPropertyValue(static_cast<UChar32>(c), UCHAR_NUMERIC_TYPE);
  return (t == U_NT_DECIMAL || t == U_NT_DIGIT) && assignedInReference(c);
}

// bpe.py's _WHITE_SPACE (the regex module's \s): a fixed set, not a table lookup.
bool isSpace(char32_t c) {
  return (c >= 0x09 && c <= 0x0D) || c == 0x20 || c == 0x85 || c == 0xA0 || c == 0x1680 || (c >= 0x2000 && c <= 0x200A) ||
         c == 0x2028 || c == 0x2029 || c == 0x202F || c == 0x205F || c == 0x3000;
}
// Python's str.strip() also strips U+001C..U+001F (bidi class B / S).
bool isPyStripSpace(char32_t c) { return isSpace(c) || (c >= 0x1C && c <= 0x1F); }

Text strip(const Text& t) {
  size_t b = 0, e = t.size();
  while (b < e && isPyStripSpace(t[b])) ++b;
  while (e > b && isPyStripSpace(t[e - 1])) --e;
  return t.substr(b, e - b);
}

// ------------------------------------------------------------------------------ fix_text

bool isRemovedControl(char32_t o) {
  return o <= 0x08 || o == 0x0B || (o >= 0x0E && o <= 0x1F) || o == 0x7F || (o >= 0x206A && o <= 0x206F) ||
         o == 0xFEFF || (o >= 0xFFF9 && o <= 0xFFFC) || (o >= 0x1D173 && o <= 0x1D17A) || (o >= 0xE0000 && o <= 0xE007F);
}

bool isLigature(char32_t c) {
  return c == 0x132 || c == 0x133 || (c >= 0x1C4 && c <= 0x1CC) || (c >= 0x1F1 && c <= 0x1F3) ||
         (c >= 0xFB00 && c <= 0xFB06);
}

char32_t straightQuote(char32_t c) {
  if (c >= 0x2018 && c <= 0x201B) return U'\'';
  if (c >= 0x201C && c <= 0x201F) return U'"';
  return c;
}

// Full-width forms folded (bpe.py _width): one character in, one or more out.
Text width(char32_t c) {
  if (c == 0x3000) return U" ";
  if (c >= 0xFF01 && c <= 0xFFEE) {
    Text n = normalized(Text(1, c), true);
    if (n.size() == 1) return n;
  }
  return Text(1, c);
}

bool isAsciiLetter(char32_t c) { return (c >= U'a' && c <= U'z') || (c >= U'A' && c <= U'Z'); }

Text stripTerminalEscapes(const Text& t) {
  Text out;
  const size_t n = t.size();
  for (size_t i = 0; i < n;) {
    if (t[i] == 0x1B && i + 1 < n && t[i + 1] == U'[') {
      size_t j = i + 2;
      while (j < n && (isPyDigit(t[j]) || t[j] == U';')) ++j;
      if (j < n && isAsciiLetter(t[j])) {
        i = j + 1;
        continue;
      }
    }
    out.push_back(t[i++]);
  }
  return out;
}

Text fixText(const Text& in) {
  const Text t = stripTerminalEscapes(in);
  Text lf;  // "\r\n" -> "\n", then "\r" -> "\n"
  for (size_t i = 0; i < t.size(); ++i) {
    if (t[i] == U'\r') {
      lf.push_back(U'\n');
      if (i + 1 < t.size() && t[i + 1] == U'\n') ++i;
    } else {
      lf.push_back(t[i]);
    }
  }
  Text out;
  for (char32_t c : lf) {
    if (isRemovedControl(c)) continue;
    Text ch = isLigature(c) ? normalized(Text(1, c), true) : Text(1, c);
    if (ch.size() == 1) {
      ch = width(straightQuote(ch[0]));
    }
    out += ch;
  }
  return normalized(out, false);
}

// ------------------------------------------------------------------------------ html.unescape

struct HtmlEntity {
  const char* name;
  uint32_t first, second;  // second 0: one code point
};
struct InvalidCharref {
  uint32_t number, replacement;
};
#include "text/html_entities.inc"

const HtmlEntity* findEntity(std::string_view name) {
  const auto it = std::lower_bound(std::begin(kHtml5Entities), std::end(kHtml5Entities), name,
                                   [](const HtmlEntity& e, std::string_view n) { return std::string_view(e.name) < n; });
  return it != std::end(kHtml5Entities) && std::string_view(it->name) == name ? it : nullptr;
}

void appendEntity(Text& out, const HtmlEntity& e) {
  out.push_back(static_cast<char32_t>(e.first));
  if (e.second) out.push_back(static_cast<char32_t>(e.second));
}

bool isAsciiDigit(char32_t c) { return c >= U'0' && c <= U'9'; }
bool isAsciiHex(char32_t c) { return isAsciiDigit(c) || (c >= U'a' && c <= U'f') || (c >= U'A' && c <= U'F'); }
int hexValue(char32_t c) { return isAsciiDigit(c) ? int(c - U'0') : int((c | 0x20) - U'a') + 10; }

// Python's html._replace_charref for a numeric reference of value num (saturated).
void appendNumeric(Text& out, uint64_t num) {
  for (const InvalidCharref& r : kInvalidCharrefs)
    if (r.number == num) {
      out.push_back(static_cast<char32_t>(r.replacement));
      return;
    }
  if ((num >= 0xD800 && num <= 0xDFFF) || num > 0x10FFFF) {
    out.push_back(0xFFFD);
    return;
  }
  if (std::binary_search(std::begin(kInvalidCodepoints), std::end(kInvalidCodepoints), static_cast<uint32_t>(num)))
    return;
  out.push_back(static_cast<char32_t>(num));
}

// Python's html.unescape: the pattern &(#[0-9]+;?|#[xX][0-9a-fA-F]+;?|[^\t\n\f <&#;]{1,32};?)
// replaced left to right, replacements not rescanned.
Text htmlUnescape(const Text& t) {
  Text out;
  const size_t n = t.size();
  size_t i = 0;
  while (i < n) {
    if (t[i] != U'&' || i + 1 >= n) {
      out.push_back(t[i++]);
      continue;
    }
    const size_t s = i + 1;
    if (t[s] == U'#') {
      const bool hex = s + 1 < n && (t[s + 1] == U'x' || t[s + 1] == U'X');
      size_t j = s + (hex ? 2 : 1);
      uint64_t num = 0;
      const size_t digits0 = j;
      while (j < n && (hex ? isAsciiHex(t[j]) : isAsciiDigit(t[j]))) {
        num = std::min<uint64_t>(num * (hex ? 16 : 10) + uint64_t(hex ? hexValue(t[j]) : int(t[j] - U'0')), 0x7FFFFFFFu);
        ++j;
      }
      if (j == digits0) {  // "&#" without digits: no alternative matches (# is excluded from names)
        out.push_back(t[i++]);
        continue;
      }
      if (j < n && t[j] == U';') ++j;
      appendNumeric(out, num);
      i = j;
      continue;
    }
    auto nameChar = [](char32_t c) {
      return c != U'\t' && c != U'\n' && c != U'\f' && c != U' ' && c != U'<' && c != U'&' && c != U'#' && c != U';';
    };
    size_t j = s;
    while (j < n && j - s < 32 && nameChar(t[j])) ++j;
    if (j == s) {
      out.push_back(t[i++]);
      continue;
    }
    if (j < n && t[j] == U';') ++j;
    const Text name = t.substr(s, j - s);
    i = j;
    // Entity names are ASCII: a name with other characters matches only through its prefix.
    auto asciiPrefix = [&name](size_t len, std::string& key) {
      key.clear();
      for (size_t k = 0; k < len; ++k) {
        if (name[k] > 0x7F) return false;
        key.push_back(static_cast<char>(name[k]));
      }
      return true;
    };
    std::string key;
    const HtmlEntity* e = asciiPrefix(name.size(), key) ? findEntity(key) : nullptr;
    if (e) {
      appendEntity(out, *e);
      continue;
    }
    bool found = false;
    for (size_t x = name.size() - 1; x > 1 && !found; --x) {
      if (asciiPrefix(x, key) && (e = findEntity(key))) {
        appendEntity(out, *e);
        out += name.substr(x);
        found = true;
      }
    }
    if (!found) {
      out.push_back(U'&');
      out += name;
    }
  }
  return out;
}

// ------------------------------------------------------------------------------ cleaning

Text whitespaceClean(const Text& t) {
  Text out;
  bool inSpace = false;
  for (char32_t c : t) {
    if (isSpace(c)) {
      if (!inSpace) out.push_back(U' ');
      inSpace = true;
    } else {
      out.push_back(c);
      inSpace = false;
    }
  }
  return strip(out);
}

Text lower(const Text& t) {
  icu::UnicodeString s = toIcu(t);
  s.toLower(icu::Locale::getRoot());  // full case mapping with final sigma, like str.lower
  return toText(s);
}

Text normalizeText(const Text& t) {
  return lower(whitespaceClean(strip(htmlUnescape(htmlUnescape(fixText(t))))));
}

const Text kSot = U"<|startoftext|>";
const Text kEot = U"<|endoftext|>";
const std::array<Text, 7> kContractions = {U"'s", U"'t", U"'re", U"'ve", U"'m", U"'ll", U"'d"};

bool startsWith(const Text& t, size_t i, const Text& p) { return t.compare(i, p.size(), p) == 0; }

std::vector<Text> preTokenizeText(const Text& t) {
  std::vector<Text> pieces;
  const size_t n = t.size();
  for (size_t i = 0; i < n;) {
    const Text* fixed = nullptr;
    if (startsWith(t, i, kSot)) fixed = &kSot;
    else if (startsWith(t, i, kEot)) fixed = &kEot;
    else
      for (const Text& c : kContractions)
        if (startsWith(t, i, c)) {
          fixed = &c;
          break;
        }
    if (fixed) {
      pieces.push_back(*fixed);
      i += fixed->size();
      continue;
    }
    const char32_t c = t[i];
    size_t j = i + 1;
    if (isLetter(c)) {
      while (j < n && isLetter(t[j])) ++j;
    } else if (isNumber(c)) {
      // one digit per piece
    } else if (isSpace(c)) {
      ++i;
      continue;
    } else {
      while (j < n && !(isSpace(t[j]) || isLetter(t[j]) || isNumber(t[j]))) ++j;
    }
    pieces.push_back(t.substr(i, j - i));
    i = j;
  }
  return pieces;
}

// ------------------------------------------------------------------------------ the table

std::vector<uint8_t> gunzip(std::span<const uint8_t> in) {
  z_stream z{};
  if (inflateInit2(&z, 16 + MAX_WBITS) != Z_OK) throw Error("BPE tokenizer: zlib inflateInit2 failed");
  std::vector<uint8_t> out;
  z.next_in = const_cast<Bytef*>(in.data());
  z.avail_in = static_cast<uInt>(in.size());
  std::array<uint8_t, 1 << 16> chunk;
  for (;;) {
    z.next_out = chunk.data();
    z.avail_out = static_cast<uInt>(chunk.size());
    const int rc = inflate(&z, Z_NO_FLUSH);
    out.insert(out.end(), chunk.data(), chunk.data() + (chunk.size() - z.avail_out));
    if (rc == Z_STREAM_END) {
      if (z.avail_in == 0) break;
      inflateReset(&z);  // another gzip member follows (Python's gzip reads them all)
      continue;
    }
    if (rc != Z_OK || (z.avail_in == 0 && z.avail_out != 0)) {
      inflateEnd(&z);
      throw Error(std::string("BPE tokenizer: the merges table does not inflate (") +
                  (rc == Z_OK ? "truncated gzip stream" : (z.msg ? z.msg : "zlib error")) + ")");
    }
  }
  inflateEnd(&z);
  return out;
}

std::vector<std::string> splitWhitespace(std::string_view line) {
  std::vector<std::string> parts;
  size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && std::string_view(" \t\r\v\f").find(line[i]) != std::string_view::npos) ++i;
    size_t j = i;
    while (j < line.size() && std::string_view(" \t\r\v\f").find(line[j]) == std::string_view::npos) ++j;
    if (j > i) parts.emplace_back(line.substr(i, j - i));
    i = j;
  }
  return parts;
}

}  // namespace

// ------------------------------------------------------------------------------ BpeTokenizer

BpeTokenizer::BpeTokenizer(std::span<const uint8_t> gzipped) {
  const std::vector<uint8_t> raw = gunzip(gzipped);
  const std::string_view text(reinterpret_cast<const char*>(raw.data()), raw.size());

  // bytes_to_unicode: printable Latin-1 bytes keep their character, the rest map to U+0100,
  // U+0101, ... in byte order; the vocabulary lists the kept bytes first.
  std::vector<int> order;
  for (int b = 0; b < 256; ++b)
    if ((b >= 0x21 && b <= 0x7E) || (b >= 0xA1 && b <= 0xAC) || (b >= 0xAE && b <= 0xFF)) order.push_back(b);
  int extra = 0;
  for (int b = 0; b < 256; ++b) {
    const bool kept = std::find(order.begin(), order.end(), b) != order.end();
    byteSymbol_[b] = toUtf8(Text(1, static_cast<char32_t>(kept ? b : 256 + extra)));
    if (!kept) {
      order.push_back(b);
      ++extra;
    }
  }

  std::vector<std::string> vocab;
  for (int b : order) vocab.push_back(byteSymbol_[b]);
  for (int b : order) vocab.push_back(byteSymbol_[b] + "</w>");
  size_t pos = text.find('\n');  // line 0 is the version header
  for (int r = 0; r < kMerges; ++r) {
    if (pos == std::string_view::npos) throw Error("BPE tokenizer: the merges table has fewer than 48894 merges");
    const size_t end = text.find('\n', pos + 1);
    const std::vector<std::string> m =
        splitWhitespace(text.substr(pos + 1, (end == std::string_view::npos ? text.size() : end) - pos - 1));
    if (m.size() != 2) throw Error("BPE tokenizer: merge line " + std::to_string(r + 1) + " is not a pair");
    ranks_.emplace(m[0] + " " + m[1], r);
    vocab.push_back(m[0] + m[1]);
    pos = end;
  }
  vocab.push_back(toUtf8(kSot));
  vocab.push_back(toUtf8(kEot));
  for (size_t i = 0; i < vocab.size(); ++i)
    if (!encoder_.emplace(vocab[i], static_cast<int32_t>(i)).second)
      throw Error("BPE tokenizer: duplicate vocabulary entry '" + vocab[i] + "'");
  sot_ = encoder_.at(toUtf8(kSot));
  eot_ = encoder_.at(toUtf8(kEot));
}

BpeTokenizer BpeTokenizer::fromFile(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw Error(path + ": cannot open the BPE merges table");
  const std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  try {
    return BpeTokenizer(bytes);
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
}

BpeTokenizer BpeTokenizer::fromModel(const PackedModel& model) {
  if (!model.has(kPackedName))
    throw Error(model.errorPrefix() + "no BPE merges table (" + kPackedName + "; pack it with spar-convert --bpe)");
  if (model.info(kPackedName).dtype != FileDType::U8)
    throw Error(model.errorPrefix() + std::string(kPackedName) + " must be U8");
  try {
    return BpeTokenizer(model.data(kPackedName));
  } catch (const Error& e) {
    throw Error(model.errorPrefix() + e.what());
  }
}

std::vector<std::string> BpeTokenizer::bpe(const std::vector<std::string>& symbols) const {
  std::vector<std::string> word = symbols;
  word.back() += "</w>";
  while (word.size() > 1) {
    int bestRank = -1;
    size_t best = 0;
    for (size_t i = 0; i + 1 < word.size(); ++i) {
      const auto it = ranks_.find(word[i] + " " + word[i + 1]);
      if (it != ranks_.end() && (bestRank < 0 || it->second < bestRank)) {
        bestRank = it->second;
        best = i;
      }
    }
    if (bestRank < 0) break;
    const std::string first = word[best], second = word[best + 1];
    std::vector<std::string> merged;
    for (size_t i = 0; i < word.size();) {
      if (i + 1 < word.size() && word[i] == first && word[i + 1] == second) {
        merged.push_back(first + second);
        i += 2;
      } else {
        merged.push_back(word[i++]);
      }
    }
    word.swap(merged);
  }
  return word;
}

std::string BpeTokenizer::normalize(const std::string& text) { return toUtf8(normalizeText(fromUtf8(text))); }

std::vector<std::string> BpeTokenizer::preTokenize(const std::string& normalized) {
  std::vector<std::string> out;
  for (const Text& p : preTokenizeText(fromUtf8(normalized))) out.push_back(toUtf8(p));
  return out;
}

std::vector<int32_t> BpeTokenizer::encode(const std::string& text) const {
  std::vector<int32_t> ids;
  for (const Text& piece : preTokenizeText(normalizeText(fromUtf8(text)))) {
    if (piece == kSot || piece == kEot) {
      ids.push_back(piece == kSot ? sot_ : eot_);
      continue;
    }
    std::vector<std::string> symbols;
    for (unsigned char b : toUtf8(piece)) symbols.push_back(byteSymbol_[b]);
    for (const std::string& tok : bpe(symbols)) ids.push_back(encoder_.at(tok));
  }
  return ids;
}

std::vector<int32_t> BpeTokenizer::tokenize(const std::vector<std::string>& prompts, int contextLength) const {
  if (contextLength < 2) throw Error("BPE tokenizer: context length " + std::to_string(contextLength) + " < 2");
  const size_t ctx = static_cast<size_t>(contextLength);
  std::vector<int32_t> out(prompts.size() * ctx, 0);
  for (size_t row = 0; row < prompts.size(); ++row) {
    std::vector<int32_t> ids{sot_};
    const std::vector<int32_t> body = encode(prompts[row]);
    ids.insert(ids.end(), body.begin(), body.end());
    ids.push_back(eot_);
    if (ids.size() > ctx) {  // CLIP's truncate=True: cut, then the end token goes back last
      ids.resize(ctx);
      ids.back() = eot_;
    }
    std::copy(ids.begin(), ids.end(), out.begin() + static_cast<std::ptrdiff_t>(row * ctx));
  }
  return out;
}

}  // namespace spar
