// model/npy: round trips of every supported dtype, headers of versions 1.0 and 2.0 as NumPy
// writes them, and one-line errors for what is not supported.
#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>

#include "spar/error.h"
#include "formats/npy.h"

namespace spar {
namespace {

namespace fs = std::filesystem;

std::string tempPath(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / "spar_test_npy";
  fs::create_directories(dir);
  return (dir / name).string();
}

void writeBytes(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// A .npy file with the given version, header dict text and payload (header padded NumPy-style).
std::string npyBytes(int major, const std::string& dict, const std::string& payload) {
  const size_t prefix = major == 1 ? 10 : 12;
  std::string header = dict;
  while ((prefix + header.size() + 1) % 64) header += ' ';
  header += '\n';
  std::string s = "\x93NUMPY";
  s += char(major);
  s += char(0);
  const uint32_t len = static_cast<uint32_t>(header.size());
  s += char(len & 0xff);
  s += char((len >> 8) & 0xff);
  if (major != 1) {
    s += char((len >> 16) & 0xff);
    s += char((len >> 24) & 0xff);
  }
  return s + header + payload;
}

std::string errorOf(const std::string& path) {
  try {
    readNpy(path);
  } catch (const Error& e) {
    const std::string m = e.what();
    EXPECT_EQ(m.find('\n'), std::string::npos) << "multi-line message: " << m;
    return m;
  }
  ADD_FAILURE() << "no error for " << path;
  return "";
}

TEST(Npy, RoundTripsEveryDtype) {
  const std::vector<float> f = {1.5f, -2.25f, 3e-30f, 65504.0f, -0.0f, 7.0f};
  const std::vector<double> d = {1.0 / 3.0, -1e300, 5e-324, 2.0, 0.0, -7.5};
  const std::vector<int32_t> i = {0, -1, 2147483647, -2147483647 - 1, 5, 6};
  const std::vector<int64_t> l = {0, -1, int64_t(1) << 62, -(int64_t(1) << 62), 5, 6};
  writeNpy(tempPath("f.npy"), {2, 3}, f.data());
  writeNpy(tempPath("d.npy"), {6}, d.data());
  writeNpy(tempPath("i.npy"), {3, 1, 2}, i.data());
  writeNpy(tempPath("l.npy"), {1, 6}, l.data());
  NpyArray a = readNpy(tempPath("f.npy"), {2, 3});
  EXPECT_EQ(a.type, NpyType::F32);
  EXPECT_EQ(0, std::memcmp(a.toFloats().data(), f.data(), f.size() * 4));
  a = readNpy(tempPath("d.npy"), {6});
  EXPECT_EQ(a.type, NpyType::F64);
  EXPECT_EQ(a.toDoubles(), d);
  a = readNpy(tempPath("i.npy"), {3, 1, 2});
  EXPECT_EQ(a.type, NpyType::I32);
  EXPECT_EQ(a.toInt64s(), std::vector<int64_t>(i.begin(), i.end()));
  a = readNpy(tempPath("l.npy"), {1, 6});
  EXPECT_EQ(a.type, NpyType::I64);
  EXPECT_EQ(a.toInt64s(), l);
  // 0-d and empty arrays.
  const float one = 4.0f;
  writeNpy(tempPath("s.npy"), {}, &one);
  a = readNpy(tempPath("s.npy"));
  EXPECT_TRUE(a.shape.empty());
  EXPECT_EQ(a.toFloats(), std::vector<float>{4.0f});
  writeNpy(tempPath("e.npy"), {0, 5}, static_cast<const float*>(nullptr));
  EXPECT_EQ(readNpy(tempPath("e.npy")).numel(), 0);
  // The data of a written file starts on a 64-byte boundary, as NumPy's does.
  EXPECT_EQ((fs::file_size(tempPath("f.npy")) - 24) % 64, 0u);
}

TEST(Npy, ReadsVersion1And2HeadersAsNumPyWritesThem) {
  std::string payload(8, '\0');
  const float v[2] = {1.0f, -2.0f};
  std::memcpy(payload.data(), v, 8);
  writeBytes(tempPath("v1.npy"), npyBytes(1, "{'descr': '<f4', 'fortran_order': False, 'shape': (2,), }", payload));
  writeBytes(tempPath("v2.npy"), npyBytes(2, "{\"descr\": \"<f4\", \"shape\": (1, 2), \"fortran_order\": False}", payload));
  EXPECT_EQ(readNpy(tempPath("v1.npy"), {2}).toFloats(), std::vector<float>({1.0f, -2.0f}));
  EXPECT_EQ(readNpy(tempPath("v2.npy"), {1, 2}).toFloats(), std::vector<float>({1.0f, -2.0f}));
}

TEST(Npy, RejectsWhatItDoesNotSupport) {
  const std::string four(4, '\0');
  struct Bad {
    std::string name, bytes, expect;
  };
  const std::vector<Bad> bad = {
      {"magic.npy", "PK\x03\x04 not an npy file at all", "bad magic"},
      {"version.npy", npyBytes(1, "{'descr': '<f4', 'fortran_order': False, 'shape': (1,), }", four).replace(6, 1, "\x04"),
       "unsupported .npy format version 4.0"},
      {"big.npy", npyBytes(1, "{'descr': '>f4', 'fortran_order': False, 'shape': (1,), }", four), "big-endian"},
      {"f2.npy", npyBytes(1, "{'descr': '<f2', 'fortran_order': False, 'shape': (2,), }", four), "'<f2' is not supported"},
      {"fortran.npy", npyBytes(1, "{'descr': '<f4', 'fortran_order': True, 'shape': (1,), }", four), "Fortran"},
      {"short.npy", npyBytes(1, "{'descr': '<f4', 'fortran_order': False, 'shape': (2,), }", four),
       "data is 4 bytes, but <f4 [2] needs 8"},
      {"long.npy", npyBytes(1, "{'descr': '<f4', 'fortran_order': False, 'shape': (), }", four + four), "data is 8 bytes"},
      {"nokey.npy", npyBytes(1, "{'descr': '<f4', 'shape': (1,), }", four), "lacks"},
      {"extra.npy", npyBytes(1, "{'descr': '<f4', 'fortran_order': False, 'shape': (1,), 'x': 1}", four), "unknown key 'x'"},
      {"shape.npy", npyBytes(1, "{'descr': '<f4', 'fortran_order': False, 'shape': (-1,), }", four), "shape"},
      {"trunc.npy", npyBytes(1, "{'descr': '<f4', 'fortran_order': False, 'shape': (1,), }", four).substr(0, 30),
       "truncated header"},
  };
  for (const auto& b : bad) {
    writeBytes(tempPath(b.name), b.bytes);
    const std::string m = errorOf(tempPath(b.name));
    EXPECT_NE(m.find(b.expect), std::string::npos) << b.name << ": " << m;
    EXPECT_NE(m.find(b.name), std::string::npos) << "message does not name the file: " << m;
  }
  EXPECT_NE(errorOf(tempPath("missing.npy")).find("cannot open"), std::string::npos);
  writeNpy(tempPath("shape2.npy"), {2}, std::vector<float>{1, 2}.data());
  EXPECT_THROW(readNpy(tempPath("shape2.npy"), {1, 2}), Error);
}

}  // namespace
}  // namespace spar
