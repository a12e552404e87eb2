#include "model/packed_model.h"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <limits>
#include <utility>

#include "engine/engine.h"
#include "spar/error.h"
#include "engine/half.h"
#include "model/quantized_matrices.h"

namespace spar {

static_assert(std::endian::native == std::endian::little, "the packed file is little-endian, like this host must be");

namespace {

// Messages are one line: control characters (from a library message or a name in the file)
// become spaces, and very long quoted parts are shortened.
std::string oneLine(std::string s) {
  for (char& c : s)
    if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) c = ' ';
  return s;
}

std::string quoted(const std::string& name) {
  std::string n = name.size() > 200 ? name.substr(0, 200) + "..." : name;
  return "'" + oneLine(n) + "'";
}

[[noreturn]] void fail(const std::string& path, const std::string& problem) {
  throw Error(oneLine(path + ": " + problem));
}

std::string range(uint64_t a, uint64_t b) { return "[" + std::to_string(a) + ", " + std::to_string(b) + ")"; }

[[noreturn]] void failTooShort(const std::string& path, uint64_t size) {
  fail(path, "file of " + std::to_string(size) + " bytes is too short for a packed model (needs an 8-byte header length)");
}

bool parseFileDType(const std::string& s, FileDType& out) {
  static const std::pair<const char*, FileDType> kTypes[] = {
      {"F32", FileDType::F32}, {"F16", FileDType::F16}, {"I32", FileDType::I32},
      {"I64", FileDType::I64}, {"U8", FileDType::U8}, {"I8", FileDType::I8}};
  for (const auto& [n, t] : kTypes)
    if (s == n) {
      out = t;
      return true;
    }
  return false;
}

}  // namespace

const char* fileDTypeName(FileDType t) {
  switch (t) {
    case FileDType::F32: return "F32";
    case FileDType::F16: return "F16";
    case FileDType::I32: return "I32";
    case FileDType::I64: return "I64";
    case FileDType::U8: return "U8";
    case FileDType::I8: return "I8";
  }
  return "?";
}

size_t fileDTypeSize(FileDType t) {
  switch (t) {
    case FileDType::F32: return 4;
    case FileDType::F16: return 2;
    case FileDType::I32: return 4;
    case FileDType::I64: return 8;
    case FileDType::U8:
    case FileDType::I8: return 1;
  }
  return 0;
}

PackedModel::PackedModel(PackedModel&& o) noexcept { *this = std::move(o); }

PackedModel& PackedModel::operator=(PackedModel&& o) noexcept {
  if (this != &o) {
    unmap();
    path_ = std::move(o.path_);
    map_ = std::exchange(o.map_, nullptr);
    size_ = std::exchange(o.size_, 0);
    owned_ = std::move(o.owned_);  // moving a vector keeps its buffer, so map_ stays valid
    dataStart_ = o.dataStart_;
    names_ = std::move(o.names_);
    tensors_ = std::move(o.tensors_);
    metadata_ = std::move(o.metadata_);
    config_ = std::move(o.config_);
    components_ = std::move(o.components_);
    card_ = std::move(o.card_);
  }
  return *this;
}

PackedModel::~PackedModel() { unmap(); }

void PackedModel::unmap() {
  if (map_ && owned_.empty()) munmap(const_cast<uint8_t*>(map_), size_);
  map_ = nullptr;
  size_ = 0;
  owned_ = {};
}

PackedModel PackedModel::fromBytes(std::vector<uint8_t> bytes, const std::string& name) {
  PackedModel m;
  m.path_ = name;
  m.owned_ = std::move(bytes);
  m.map_ = m.owned_.empty() ? nullptr : m.owned_.data();
  m.size_ = m.owned_.size();
  m.parseHeader();
  return m;
}

PackedModel PackedModel::open(const std::string& path) {
  PackedModel m;
  m.path_ = path;

  // Map the file (read-only). The object owns the mapping from here on, so every throw below
  // unmaps it.
  int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) fail(path, std::string("cannot open: ") + std::strerror(errno));
  struct stat st {};
  if (fstat(fd, &st) != 0) {
    int e = errno;
    ::close(fd);
    fail(path, std::string("cannot stat: ") + std::strerror(e));
  }
  if (!S_ISREG(st.st_mode)) {
    ::close(fd);
    fail(path, "not a regular file");
  }
  const uint64_t size = static_cast<uint64_t>(st.st_size);
  if (size < 8) {  // checked before mmap, which refuses an empty file
    ::close(fd);
    failTooShort(path, size);
  }
  void* p = mmap(nullptr, size, PROT_READ, MAP_PRIVATE, fd, 0);
  int mapErrno = errno;
  ::close(fd);
  if (p == MAP_FAILED) fail(path, std::string("cannot memory-map: ") + std::strerror(mapErrno));
  m.map_ = static_cast<const uint8_t*>(p);
  m.size_ = size;
  m.parseHeader();
  return m;
}

void PackedModel::parseHeader() {
  // The names open() gave these when the checks were its body.
  PackedModel& m = *this;
  const std::string& path = path_;
  const uint64_t size = size_;
  if (size < 8) failTooShort(path, size);

  // Header length and JSON.
  uint64_t headerLen = 0;
  std::memcpy(&headerLen, m.map_, 8);
  if (headerLen > size - 8)
    fail(path, "header length " + std::to_string(headerLen) + " runs past the end of the file (" +
                   std::to_string(size) + " bytes)");
  m.dataStart_ = 8 + headerLen;
  const uint64_t dataBytes = size - m.dataStart_;

  nlohmann::json header;
  try {
    const char* h = reinterpret_cast<const char*>(m.map_ + 8);
    header = nlohmann::json::parse(h, h + headerLen);
  } catch (const nlohmann::json::exception& e) {
    fail(path, std::string("header is not valid JSON: ") + e.what());
  }
  if (!header.is_object()) fail(path, "header is not a JSON object");
  parseMetadata(header);
  parseTensors(header, dataBytes);
  checkNoOverlap();
  parseQuantized();
}

// Metadata: all strings; format, version, config, and the optional components and model card.
void PackedModel::parseMetadata(const nlohmann::json& header) {
  PackedModel& m = *this;
  const std::string& path = path_;
  auto metaIt = header.find("__metadata__");
  if (metaIt == header.end()) fail(path, "no __metadata__ in the header (not a spar-vulkan packed model)");
  if (!metaIt->is_object()) fail(path, "__metadata__ is not a JSON object");
  for (auto it = metaIt->begin(); it != metaIt->end(); ++it) {
    if (!it.value().is_string()) fail(path, "__metadata__ value " + quoted(it.key()) + " is not a string");
    m.metadata_[it.key()] = it.value().get<std::string>();
  }
  auto metaValue = [&](const char* key) -> const std::string& {
    auto it = m.metadata_.find(key);
    if (it == m.metadata_.end()) fail(path, std::string("__metadata__ has no '") + key + "' (not a spar-vulkan packed model)");
    return it->second;
  };
  if (metaValue("format") != kFormat)
    fail(path, "format " + quoted(metaValue("format")) + " is not '" + kFormat + "'");
  const std::string& version = metaValue("format_version");
  if (version != kFormatVersion && version != kQuantFormatVersion)
    fail(path, "unsupported format_version " + quoted(version) + " (this reader knows '" + kFormatVersion + "' and '" +
                   kQuantFormatVersion + "')");
  if ((version == kQuantFormatVersion) != (m.metadata_.count("quantized") != 0))
    fail(path, version == kQuantFormatVersion ? "format_version '2' without __metadata__ quantized"
                                              : "__metadata__ quantized in a format_version '1' file");
  try {
    m.config_ = nlohmann::json::parse(metaValue("config"));
  } catch (const nlohmann::json::exception& e) {
    fail(path, std::string("__metadata__ config is not valid JSON: ") + e.what());
  }
  if (!m.config_.is_object()) fail(path, "__metadata__ config is not a JSON object");
  if (auto it = m.metadata_.find("components"); it != m.metadata_.end()) {
    try {
      m.components_ = nlohmann::json::parse(it->second);
    } catch (const nlohmann::json::exception& e) {
      fail(path, std::string("__metadata__ components is not valid JSON: ") + e.what());
    }
    if (!m.components_.is_object()) fail(path, "__metadata__ components is not a JSON object");
  }
  if (auto it = m.metadata_.find("model_card"); it != m.metadata_.end()) {
    try {
      m.card_ = parseModelCard(it->second);
    } catch (const Error& e) {
      fail(path, e.what());
    }
  }
}

// Every tensor entry: its dtype, shape and data offsets, inside the data area and as long as
// its shape needs.
void PackedModel::parseTensors(const nlohmann::json& header, uint64_t dataBytes) {
  PackedModel& m = *this;
  const std::string& path = path_;
  for (auto it = header.begin(); it != header.end(); ++it) {
    const std::string& name = it.key();
    if (name == "__metadata__") continue;
    const std::string t = "tensor " + quoted(name);
    if (name.empty()) fail(path, "a tensor has an empty name");
    const auto& e = it.value();
    if (!e.is_object()) fail(path, t + ": entry is not a JSON object");
    PackedTensorInfo info;

    auto dt = e.find("dtype");
    if (dt == e.end() || !dt->is_string()) fail(path, t + ": no dtype string");
    if (!parseFileDType(dt->get<std::string>(), info.dtype))
      fail(path, t + ": unsupported dtype " + quoted(dt->get<std::string>()) + " (known: F32, F16, I32, I64, U8, I8)");

    auto sh = e.find("shape");
    if (sh == e.end() || !sh->is_array()) fail(path, t + ": no shape list");
    uint64_t numel = 1;
    bool overflow = false;
    for (const auto& d : *sh) {
      if (!d.is_number_unsigned()) fail(path, t + ": shape " + oneLine(sh->dump()) + " is not a list of non-negative integers");
      const uint64_t v = d.get<uint64_t>();
      if (v > static_cast<uint64_t>(std::numeric_limits<int64_t>::max())) overflow = true;
      overflow = overflow || __builtin_mul_overflow(numel, v, &numel);
      info.shape.push_back(static_cast<int64_t>(v));
    }
    uint64_t want = 0;
    overflow = overflow || __builtin_mul_overflow(numel, fileDTypeSize(info.dtype), &want);
    if (overflow) fail(path, t + ": shape " + oneLine(sh->dump()) + " is too large");

    auto off = e.find("data_offsets");
    if (off == e.end() || !off->is_array() || off->size() != 2 || !(*off)[0].is_number_unsigned() ||
        !(*off)[1].is_number_unsigned())
      fail(path, t + ": data_offsets is not a pair of non-negative integers");
    info.begin = (*off)[0].get<uint64_t>();
    info.end = (*off)[1].get<uint64_t>();
    if (info.end < info.begin) fail(path, t + ": data_offsets " + range(info.begin, info.end) + " end before they begin");
    if (info.end > dataBytes)
      fail(path, t + " data " + range(info.begin, info.end) + " lies outside the file (its data area holds " +
                     std::to_string(dataBytes) + " bytes)");
    if (info.end - info.begin != want)
      fail(path, t + ": " + fileDTypeName(info.dtype) + " " + shapeString(info.shape) + " needs " + std::to_string(want) +
                     " bytes but data_offsets " + range(info.begin, info.end) + " span " +
                     std::to_string(info.end - info.begin));
    m.names_.push_back(name);
    m.tensors_.emplace(name, std::move(info));
  }
}

// No two tensors share a byte.
void PackedModel::checkNoOverlap() {
  PackedModel& m = *this;
  const std::string& path = path_;
  std::sort(m.names_.begin(), m.names_.end(), [&](const std::string& a, const std::string& b) {
    const auto &x = m.tensors_.at(a), &y = m.tensors_.at(b);
    return x.begin != y.begin ? x.begin < y.begin : (x.end != y.end ? x.end < y.end : a < b);
  });
  const std::string* last = nullptr;  // the tensor reaching furthest so far
  for (const auto& name : m.names_) {
    const auto& info = m.tensors_.at(name);
    if (info.bytes() == 0) continue;
    if (last) {
      const auto& prev = m.tensors_.at(*last);
      if (info.begin < prev.end)
        fail(path, "tensors " + quoted(*last) + " " + range(prev.begin, prev.end) + " and " + quoted(name) + " " +
                       range(info.begin, info.end) + " overlap");
      if (info.end <= prev.end) continue;
    }
    last = &name;
  }
}

void PackedModel::parseQuantized() {
  auto it = metadata_.find("quantized");
  if (it == metadata_.end()) return;
  nlohmann::json q;
  try {
    q = nlohmann::json::parse(it->second);
  } catch (const nlohmann::json::exception& e) {
    fail(path_, std::string("__metadata__ quantized is not valid JSON: ") + e.what());
  }
  if (!q.is_object()) fail(path_, "__metadata__ quantized is not a JSON object");
  for (auto e = q.begin(); e != q.end(); ++e) {
    const std::string& name = e.key();
    const std::string t = "quantized tensor " + quoted(name);
    const nlohmann::json& r = e.value();
    auto field = [&](const char* key) -> const nlohmann::json& {
      if (!r.is_object() || !r.contains(key)) fail(path_, t + ": no '" + key + "' in its __metadata__ quantized record");
      return r.at(key);
    };
    const nlohmann::json &bitsJ = field("bits"), &blockJ = field("block"), &shapeJ = field("shape");
    if (!bitsJ.is_number_integer() || (bitsJ.get<int64_t>() != 8 && bitsJ.get<int64_t>() != 4))
      fail(path_, t + ": bit width " + oneLine(bitsJ.dump()) + " (this reader knows 8 and 4)");
    if (!blockJ.is_number_integer() || blockJ.get<int64_t>() != 32)
      fail(path_, t + ": block of " + oneLine(blockJ.dump()) + " values (this reader knows 32)");
    // [N, K], or a convolution kernel [Cout, Cin, kh, kw]: the matrix [Cout, Cin*kh*kw]
    bool shapeOk = shapeJ.is_array() && (shapeJ.size() == 2 || shapeJ.size() == 4);
    Shape logical;
    uint64_t rowValues = 1;
    for (size_t d = 0; shapeOk && d < shapeJ.size(); ++d) {
      shapeOk = shapeJ[d].is_number_unsigned() && shapeJ[d].get<uint64_t>() <= (uint64_t(1) << 31);
      if (!shapeOk) break;
      logical.push_back(shapeJ[d].get<int64_t>());
      if (d) rowValues *= shapeJ[d].get<uint64_t>();
      shapeOk = rowValues <= (uint64_t(1) << 31);
    }
    if (!shapeOk) fail(path_, t + ": shape " + oneLine(shapeJ.dump()) + " is not [N, K] nor [Cout, Cin, kh, kw]");
    const int bits = bitsJ.get<int>();
    const int64_t n = logical[0], k = int64_t(rowValues);
    if (k % 32) fail(path_, t + ": rows of " + std::to_string(k) + " values are not whole blocks of 32");
    auto codes = tensors_.find(name);
    if (codes == tensors_.end()) fail(path_, t + ": no tensor of its codes");
    PackedTensorInfo& c = codes->second;
    const FileDType want = bits == 8 ? FileDType::I8 : FileDType::U8;
    const Shape codesShape = {n, bits == 8 ? k : k / 2};
    if (c.dtype != want || c.shape != codesShape)
      fail(path_, t + ": codes are " + fileDTypeName(c.dtype) + " " + shapeString(c.shape) + ", " + std::to_string(bits) +
                      "-bit codes of " + shapeString({n, k}) + " are " + fileDTypeName(want) + " " + shapeString(codesShape));
    const std::string scaleName = name + ".qscale";
    auto scales = tensors_.find(scaleName);
    const Shape scaleShape = {n, k / 32};
    if (scales == tensors_.end() || scales->second.dtype != FileDType::F32 || scales->second.shape != scaleShape)
      fail(path_, t + ": its scales " + quoted(scaleName) + " are " +
                      (scales == tensors_.end() ? std::string("missing")
                                                : std::string(fileDTypeName(scales->second.dtype)) + " " +
                                                      shapeString(scales->second.shape)) +
                      ", not F32 " + shapeString(scaleShape) + " (one per block of 32)");
    c.shape = logical;
    c.quantBits = bits;
    c.scales = scaleName;
  }
}

void PackedModel::checkScales(const std::string& name) const {
  const auto& i = info(name);
  const auto bytes = data(i.scales);
  // The largest code magnitude (128: an int8 of -128; 8: a nibble of 0) times the scale must stay
  // a finite float, or a value would be infinite.
  const float largest = std::numeric_limits<float>::max() / (i.quantBits == 8 ? 128.0f : 8.0f);
  for (size_t b = 0; b < bytes.size() / 4; ++b) {
    float s;
    std::memcpy(&s, bytes.data() + 4 * b, 4);
    if (!(s >= 0.0f && s <= largest))
      fail(path_, "quantized tensor " + quoted(name) + ": block " + std::to_string(b) + " has the scale " +
                      std::to_string(s) + " (a scale is finite, not negative, and at most float's largest / " +
                      (i.quantBits == 8 ? "128" : "8") + "; the file is damaged)");
  }
}

const PackedTensorInfo& PackedModel::info(const std::string& name) const {
  auto it = tensors_.find(name);
  if (it == tensors_.end()) fail(path_, "no tensor " + quoted(name));
  return it->second;
}

std::span<const uint8_t> PackedModel::data(const std::string& name) const {
  const auto& i = info(name);
  return {map_ + dataStart_ + i.begin, static_cast<size_t>(i.bytes())};
}

// A weight that is NaN or infinite makes every output it touches NaN (a black view, null
// cameras): refuse it when it is read, naming the tensor, as spar-convert refuses to pack one.
// Checked on the bits (exponent all ones), which costs a pass over the bytes and no conversion.
void PackedModel::checkFinite(const std::string& name) const {
  const auto& i = info(name);
  if (i.quantBits) return checkScales(name);
  const auto bytes = data(name);
  const size_t n = static_cast<size_t>(i.numel());
  auto bad = [&](size_t k, bool nan) {
    fail(path_, "tensor " + quoted(name) + " element " + std::to_string(k) + " is " + (nan ? "NaN" : "infinite") +
                    " (the file is damaged, or the model diverged in training)");
  };
  if (i.dtype == FileDType::F32) {
    for (size_t k = 0; k < n; ++k) {
      uint32_t b;
      std::memcpy(&b, bytes.data() + 4 * k, 4);
      if ((b & 0x7f800000u) == 0x7f800000u) bad(k, b & 0x007fffffu);
    }
  } else if (i.dtype == FileDType::F16) {
    for (size_t k = 0; k < n; ++k) {
      uint16_t b;
      std::memcpy(&b, bytes.data() + 2 * k, 2);
      if ((b & 0x7c00u) == 0x7c00u) bad(k, b & 0x03ffu);
    }
  }
}

std::vector<float> PackedModel::floats(const std::string& name) const {
  checkFinite(name);
  const auto& i = info(name);
  const auto bytes = data(name);
  const size_t n = static_cast<size_t>(i.numel());
  std::vector<float> out(n);
  if (i.quantBits) {  // code * scale, as the kernels compute it (float32)
    const auto scales = data(i.scales);
    for (size_t e = 0; e < n; ++e) {
      float s;
      std::memcpy(&s, scales.data() + 4 * (e / 32), 4);
      const int code = i.quantBits == 8 ? int(int8_t(bytes[e])) : int((bytes[e / 2] >> (4 * (e & 1))) & 0xF) - 8;
      out[e] = float(code) * s;
    }
  } else if (i.dtype == FileDType::F32) {
    if (n) std::memcpy(out.data(), bytes.data(), n * 4);
  } else if (i.dtype == FileDType::F16) {
    for (size_t k = 0; k < n; ++k) {
      uint16_t h;
      std::memcpy(&h, bytes.data() + 2 * k, 2);
      out[k] = halfToFloat(h);
    }
  } else {
    fail(path_, "tensor " + quoted(name) + " is " + fileDTypeName(i.dtype) + ", not floating point");
  }
  return out;
}

DType PackedModel::naturalDType(const std::string& name) const {
  const auto& i = info(name);
  if (i.quantBits) return i.quantBits == 8 ? DType::Q8 : DType::Q4;
  switch (i.dtype) {
    case FileDType::F32: return DType::F32;
    case FileDType::F16: return DType::F16;
    case FileDType::I32:
    case FileDType::I64: return DType::I32;
    case FileDType::U8:
    case FileDType::I8: break;
  }
  fail(path_, "tensor " + quoted(name) + " is " + fileDTypeName(i.dtype) + " " + shapeString(i.shape) +
                  ": the engine has no such tensor type (read it with data())");
}

Tensor PackedModel::upload(Engine& engine, const std::string& name, DType want) const {
  checkFinite(name);
  const auto& i = info(name);
  const auto bytes = data(name);
  if (i.quantBits) {  // each row's codes, then its scales (engine/tensor.h, DType::Q8 / Q4)
    const DType q = naturalDType(name);
    if (want != q)
      fail(path_, "tensor " + quoted(name) + " is a " + dtypeName(q) + " matrix " + shapeString(i.shape) +
                      ": this stage reads it as " + dtypeName(want) + " (quantized matrices reach only the kernels that dequantize them; "
                      "convert the model with --weights fp32 or fp16)");
    const auto scales = data(i.scales);
    const Shape matrix = quantizedMatrixShape(i.shape);
    const int64_t rows = matrix[0], k = matrix[1];
    const size_t codeBytes = size_t(k) * size_t(i.quantBits) / 8, scaleBytes = size_t(k) / 32 * 4;
    std::vector<uint8_t> v(size_t(rows) * (codeBytes + scaleBytes));
    for (int64_t r = 0; r < rows; ++r) {
      uint8_t* dst = v.data() + size_t(r) * (codeBytes + scaleBytes);
      std::memcpy(dst, bytes.data() + size_t(r) * codeBytes, codeBytes);
      std::memcpy(dst + codeBytes, scales.data() + size_t(r) * scaleBytes, scaleBytes);
    }
    Tensor t = engine.tensor(matrix, q);
    if (!v.empty()) engine.write(t, v.data(), v.size());
    return t;
  }
  const size_t n = static_cast<size_t>(i.numel());
  const bool isFloat = i.dtype == FileDType::F32 || i.dtype == FileDType::F16;
  const bool isInt = i.dtype == FileDType::I32 || i.dtype == FileDType::I64;
  const bool wantFloat = want == DType::F32 || want == DType::F16;
  if (!((isFloat && wantFloat) || (isInt && want == DType::I32)))
    fail(path_, "tensor " + quoted(name) + " is " + fileDTypeName(i.dtype) + " " + shapeString(i.shape) +
                    ": cannot upload it as " + dtypeName(want) + " (F32/F16 load as f32 or f16, I32/I64 as i32)");

  auto put = [&](const Tensor& t, const void* src, size_t count) {
    if (count) engine.write(t, src, count);
  };


  // Converted on the host first, so a refusal (I64 out of range) allocates nothing.
  if (i.dtype == FileDType::I64) {
    std::vector<int32_t> v(n);
    for (size_t k = 0; k < n; ++k) {
      int64_t x;
      std::memcpy(&x, bytes.data() + 8 * k, 8);
      if (x < std::numeric_limits<int32_t>::min() || x > std::numeric_limits<int32_t>::max())
        fail(path_, "tensor " + quoted(name) + " element " + std::to_string(k) + " = " + std::to_string(x) +
                        " does not fit i32");
      v[k] = static_cast<int32_t>(x);
    }
    Tensor t = engine.tensor(i.shape, want);
    put(t, v.data(), n * 4);
    return t;
  }
  if ((i.dtype == FileDType::F32 && want == DType::F32) || (i.dtype == FileDType::F16 && want == DType::F16) ||
      (i.dtype == FileDType::I32 && want == DType::I32)) {
    Tensor t = engine.tensor(i.shape, want);
    put(t, bytes.data(), bytes.size());
    return t;
  }
  if (i.dtype == FileDType::F16) {  // -> F32
    Tensor t = engine.tensor(i.shape, want);
    std::vector<float> v = floats(name);
    put(t, v.data(), n * 4);
    return t;
  }
  // F32 -> F16, saturating at the fp16 maximum like Engine::upload (NaN stays NaN).
  std::vector<uint16_t> h(n);
  for (size_t k = 0; k < n; ++k) {
    float x;
    std::memcpy(&x, bytes.data() + 4 * k, 4);
    h[k] = floatToHalf(std::isnan(x) ? x : std::clamp(x, -65504.0f, 65504.0f));
  }
  Tensor t = engine.tensor(i.shape, want);
  put(t, h.data(), n * 2);
  return t;
}

}  // namespace spar
