#include "formats/npy.h"

#include <bit>
#include <cctype>
#include <cstring>
#include <fstream>
#include <limits>

#include "spar/error.h"

namespace spar {
namespace {

static_assert(std::endian::native == std::endian::little, "npy.cpp assumes a little-endian host");

constexpr char kMagic[] = "\x93NUMPY";
constexpr size_t kMagicLen = 6;

[[noreturn]] void fail(const std::string& path, const std::string& what) {
  throw Error("npy " + path + ": " + what);
}

// A parser for the header's Python dict literal, e.g.
// {'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }
class HeaderParser {
 public:
  HeaderParser(const std::string& path, const std::string& text) : path_(path), s_(text) {}

  void parse(std::string& descr, bool& fortran, std::vector<int64_t>& shape) {
    bool haveDescr = false, haveFortran = false, haveShape = false;
    expect('{');
    while (true) {
      skipSpace();
      if (peek() == '}') {
        ++i_;
        break;
      }
      const std::string key = stringLiteral();
      expect(':');
      skipSpace();
      if (key == "descr") {
        if (haveDescr) fail(path_, "header repeats 'descr'");
        descr = stringLiteral();
        haveDescr = true;
      } else if (key == "fortran_order") {
        if (haveFortran) fail(path_, "header repeats 'fortran_order'");
        fortran = boolLiteral();
        haveFortran = true;
      } else if (key == "shape") {
        if (haveShape) fail(path_, "header repeats 'shape'");
        shape = tupleLiteral();
        haveShape = true;
      } else {
        fail(path_, "header has an unknown key '" + key + "'");
      }
      skipSpace();
      if (peek() == ',') {
        ++i_;
        continue;
      }
      expect('}');
      break;
    }
    skipSpace();
    if (i_ != s_.size()) fail(path_, "header has text after its dict");
    if (!haveDescr || !haveFortran || !haveShape)
      fail(path_, "header lacks one of 'descr', 'fortran_order', 'shape'");
  }

 private:
  char peek() const { return i_ < s_.size() ? s_[i_] : '\0'; }
  void skipSpace() {
    while (i_ < s_.size() && std::isspace(static_cast<unsigned char>(s_[i_]))) ++i_;
  }
  void expect(char c) {
    skipSpace();
    if (peek() != c) fail(path_, std::string("header is not a valid dict (expected '") + c + "' at offset " +
                                     std::to_string(i_) + ")");
    ++i_;
  }
  std::string stringLiteral() {
    skipSpace();
    const char q = peek();
    if (q != '\'' && q != '"') fail(path_, "header is not a valid dict (expected a string at offset " + std::to_string(i_) + ")");
    const size_t end = s_.find(q, i_ + 1);
    if (end == std::string::npos) fail(path_, "header has an unterminated string");
    std::string out = s_.substr(i_ + 1, end - i_ - 1);
    i_ = end + 1;
    return out;
  }
  bool boolLiteral() {
    if (s_.compare(i_, 4, "True") == 0) {
      i_ += 4;
      return true;
    }
    if (s_.compare(i_, 5, "False") == 0) {
      i_ += 5;
      return false;
    }
    fail(path_, "header's 'fortran_order' is not True or False");
  }
  std::vector<int64_t> tupleLiteral() {
    std::vector<int64_t> dims;
    expect('(');
    while (true) {
      skipSpace();
      if (peek() == ')') {
        ++i_;
        return dims;
      }
      if (!std::isdigit(static_cast<unsigned char>(peek())))
        fail(path_, "header's 'shape' is not a tuple of non-negative integers");
      int64_t v = 0;
      while (std::isdigit(static_cast<unsigned char>(peek()))) {
        const int digit = s_[i_++] - '0';
        if (v > (std::numeric_limits<int64_t>::max() - digit) / 10) fail(path_, "header's 'shape' overflows");
        v = v * 10 + digit;
      }
      if (peek() == 'L') ++i_;  // Python 2 longs
      dims.push_back(v);
      skipSpace();
      if (peek() == ',') {
        ++i_;
        continue;
      }
      expect(')');
      return dims;
    }
  }

  const std::string& path_;
  const std::string& s_;
  size_t i_ = 0;
};

bool typeFromDescr(const std::string& d, NpyType& t) {
  if (d == "<f4") t = NpyType::F32;
  else if (d == "<f8") t = NpyType::F64;
  else if (d == "<i4") t = NpyType::I32;
  else if (d == "<i8") t = NpyType::I64;
  else return false;
  return true;
}

std::string shapeText(const std::vector<int64_t>& shape) {
  std::string s = "(";
  for (size_t i = 0; i < shape.size(); ++i)
    s += std::to_string(shape[i]) + (shape.size() == 1 ? "," : i + 1 < shape.size() ? ", " : "");
  return s + ")";
}

std::string shapeList(const std::vector<int64_t>& shape) {
  std::string s = "[";
  for (size_t i = 0; i < shape.size(); ++i) s += (i ? ", " : "") + std::to_string(shape[i]);
  return s + "]";
}

template <class Out, class In>
std::vector<Out> convertAll(const NpyArray& a) {
  std::vector<Out> out(static_cast<size_t>(a.numel()));
  for (size_t i = 0; i < out.size(); ++i) {
    In v;
    std::memcpy(&v, a.data.data() + i * sizeof(In), sizeof(In));
    out[i] = static_cast<Out>(v);
  }
  return out;
}

template <class Out>
std::vector<Out> convert(const NpyArray& a) {
  switch (a.type) {
    case NpyType::F32: return convertAll<Out, float>(a);
    case NpyType::F64: return convertAll<Out, double>(a);
    case NpyType::I32: return convertAll<Out, int32_t>(a);
    case NpyType::I64: return convertAll<Out, int64_t>(a);
  }
  return {};
}

template <class T>
void writeTyped(const std::string& path, const std::vector<int64_t>& shape, const T* values, NpyType type) {
  NpyArray a;
  a.type = type;
  a.shape = shape;
  const int64_t n = a.numel();
  if (n < 0) throw Error("npy " + path + ": negative dimension in shape " + shapeList(shape));
  a.data.resize(static_cast<size_t>(n) * sizeof(T));
  if (n) std::memcpy(a.data.data(), values, a.data.size());
  writeNpy(path, a);
}

}  // namespace

const char* npyTypeName(NpyType t) {
  switch (t) {
    case NpyType::F32: return "<f4";
    case NpyType::F64: return "<f8";
    case NpyType::I32: return "<i4";
    case NpyType::I64: return "<i8";
  }
  return "?";
}

size_t npyTypeSize(NpyType t) { return t == NpyType::F32 || t == NpyType::I32 ? 4 : 8; }

int64_t NpyArray::numel() const {
  int64_t n = 1;
  for (int64_t d : shape) n *= d;
  return n;
}

std::vector<float> NpyArray::toFloats() const { return convert<float>(*this); }
std::vector<double> NpyArray::toDoubles() const { return convert<double>(*this); }
std::vector<int64_t> NpyArray::toInt64s() const {
  if (type == NpyType::F32 || type == NpyType::F64)
    throw Error(std::string("npy: toInt64s on a floating-point array (") + npyTypeName(type) + ")");
  return convert<int64_t>(*this);
}

NpyArray readNpy(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(path, "cannot open the file");
  in.seekg(0, std::ios::end);
  const std::streamoff fileSize = in.tellg();
  in.seekg(0, std::ios::beg);

  unsigned char pre[10];
  if (fileSize < 10 || !in.read(reinterpret_cast<char*>(pre), 8)) fail(path, "too short to be a .npy file");
  if (std::memcmp(pre, kMagic, kMagicLen) != 0) fail(path, "not a .npy file (bad magic)");
  const int major = pre[6], minor = pre[7];
  if (minor != 0 || major < 1 || major > 3)
    fail(path, "unsupported .npy format version " + std::to_string(major) + "." + std::to_string(minor));
  uint64_t headerLen = 0;
  size_t prefix = 0;
  if (major == 1) {
    if (!in.read(reinterpret_cast<char*>(pre + 8), 2)) fail(path, "truncated header");
    headerLen = uint64_t(pre[8]) | uint64_t(pre[9]) << 8;
    prefix = 10;
  } else {
    unsigned char len[4];
    if (!in.read(reinterpret_cast<char*>(len), 4)) fail(path, "truncated header");
    headerLen = uint64_t(len[0]) | uint64_t(len[1]) << 8 | uint64_t(len[2]) << 16 | uint64_t(len[3]) << 24;
    prefix = 12;
  }
  if (static_cast<uint64_t>(fileSize) < prefix + headerLen) fail(path, "truncated header");
  std::string header(headerLen, '\0');
  if (!in.read(header.data(), static_cast<std::streamsize>(headerLen))) fail(path, "truncated header");
  if (header.empty() || header.back() != '\n') fail(path, "header does not end with a newline");
  header.pop_back();

  std::string descr;
  bool fortran = false;
  NpyArray a;
  HeaderParser(path, header).parse(descr, fortran, a.shape);
  if (!typeFromDescr(descr, a.type)) {
    if (!descr.empty() && descr[0] == '>') fail(path, "big-endian dtype '" + descr + "' is not supported");
    fail(path, "dtype '" + descr + "' is not supported (only <f4, <f8, <i4, <i8)");
  }
  if (fortran) fail(path, "Fortran-order arrays are not supported");

  const uint64_t elemSize = npyTypeSize(a.type);
  uint64_t n = 1;
  for (int64_t d : a.shape) {
    if (d != 0 && n > std::numeric_limits<uint64_t>::max() / elemSize / uint64_t(d)) fail(path, "shape overflows");
    n *= uint64_t(d);
  }
  const uint64_t dataBytes = n * elemSize;
  const uint64_t available = static_cast<uint64_t>(fileSize) - prefix - headerLen;
  if (available != dataBytes)
    fail(path, "data is " + std::to_string(available) + " bytes, but " + descr + " " + shapeList(a.shape) +
                   " needs " + std::to_string(dataBytes));
  a.data.resize(dataBytes);
  if (dataBytes && !in.read(reinterpret_cast<char*>(a.data.data()), static_cast<std::streamsize>(dataBytes)))
    fail(path, "read error in the data");
  return a;
}

NpyArray readNpy(const std::string& path, const std::vector<int64_t>& shape) {
  NpyArray a = readNpy(path);
  if (a.shape != shape) fail(path, "shape " + shapeList(a.shape) + ", expected " + shapeList(shape));
  return a;
}

void writeNpy(const std::string& path, const NpyArray& a) {
  for (int64_t d : a.shape)
    if (d < 0) fail(path, "negative dimension in shape " + shapeList(a.shape));
  if (a.data.size() != static_cast<size_t>(a.numel()) * npyTypeSize(a.type))
    fail(path, "data size " + std::to_string(a.data.size()) + " does not match " + npyTypeName(a.type) + " " +
                   shapeList(a.shape));
  std::string header = std::string("{'descr': '") + npyTypeName(a.type) + "', 'fortran_order': False, 'shape': " +
                       shapeText(a.shape) + ", }";
  // Pad with spaces so that the data starts on a 64-byte boundary; the header ends with '\n'.
  size_t prefix = 10;
  size_t total = prefix + header.size() + 1;
  int major = 1;
  if ((total + 63) / 64 * 64 - prefix > 65535) {
    major = 2;
    prefix = 12;
    total = prefix + header.size() + 1;
  }
  const size_t padded = (total + 63) / 64 * 64;
  header.append(padded - total, ' ');
  header.push_back('\n');
  const uint64_t len = header.size();

  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) fail(path, "cannot create the file");
  out.write(kMagic, kMagicLen);
  const char version[2] = {static_cast<char>(major), 0};
  out.write(version, 2);
  if (major == 1) {
    const char l[2] = {static_cast<char>(len & 0xff), static_cast<char>(len >> 8)};
    out.write(l, 2);
  } else {
    const char l[4] = {static_cast<char>(len & 0xff), static_cast<char>((len >> 8) & 0xff),
                       static_cast<char>((len >> 16) & 0xff), static_cast<char>((len >> 24) & 0xff)};
    out.write(l, 4);
  }
  out.write(header.data(), static_cast<std::streamsize>(header.size()));
  out.write(reinterpret_cast<const char*>(a.data.data()), static_cast<std::streamsize>(a.data.size()));
  out.close();
  if (!out) fail(path, "write error");
}

void writeNpy(const std::string& path, const std::vector<int64_t>& shape, const float* values) {
  writeTyped(path, shape, values, NpyType::F32);
}
void writeNpy(const std::string& path, const std::vector<int64_t>& shape, const double* values) {
  writeTyped(path, shape, values, NpyType::F64);
}
void writeNpy(const std::string& path, const std::vector<int64_t>& shape, const int32_t* values) {
  writeTyped(path, shape, values, NpyType::I32);
}
void writeNpy(const std::string& path, const std::vector<int64_t>& shape, const int64_t* values) {
  writeTyped(path, shape, values, NpyType::I64);
}

}  // namespace spar
