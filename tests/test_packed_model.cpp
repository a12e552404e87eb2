// The packed weight file reader (model/packed_model.*) and the on-demand weight set
// (model/weight_set.*): a tiny model made by the converter at test time (CTest fixture
// tiny_model, path in SPAR_TINY_MODEL), and hand-made valid and corrupt files.
#include <unistd.h>

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "engine/half.h"
#include "model/packed_model.h"
#include "model/spar_config.h"
#include "model/weight_set.h"
#include "tests/test_support.h"

#ifndef SPAR_TINY_MODEL
#error "SPAR_TINY_MODEL (path of the tiny packed model) must be defined by tests/CMakeLists.txt"
#endif

namespace spar::test {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

const std::string kTiny = SPAR_TINY_MODEL;

std::vector<uint8_t> readFile(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

void writeFile(const std::string& path, const std::vector<uint8_t>& bytes) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
}

// 8-byte length + header + data; headerLength overrides the stored length when given.
std::vector<uint8_t> packFile(const std::string& header, const std::vector<uint8_t>& data,
                              std::optional<uint64_t> headerLength = std::nullopt) {
  uint64_t n = headerLength ? *headerLength : header.size();
  std::vector<uint8_t> out(8 + header.size() + data.size());
  std::memcpy(out.data(), &n, 8);
  if (!header.empty()) std::memcpy(out.data() + 8, header.data(), header.size());
  if (!data.empty()) std::memcpy(out.data() + 8 + header.size(), data.data(), data.size());
  return out;
}

json goodMetadata() {
  return {{"format", "spar-vulkan"}, {"format_version", "1"}, {"config", R"({"d": 8})"}};
}

template <class T>
void append(std::vector<uint8_t>& data, const std::vector<T>& values) {
  const auto* p = reinterpret_cast<const uint8_t*>(values.data());
  data.insert(data.end(), p, p + values.size() * sizeof(T));
}

class PackedModelTest : public EngineTest {
 protected:
  void SetUp() override {
    EngineTest::SetUp();
    if (!fs::exists(kTiny))
      GTEST_SKIP() << kTiny << " is missing: run through ctest (fixture make_tiny_model), or `ctest -R make_tiny_model` first";
  }
};

class HandMadeFileTest : public EngineTest {
 protected:
  void SetUp() override {
    EngineTest::SetUp();
    dir_ = fs::temp_directory_path() / ("spar_packed_model_" + std::to_string(getpid()));
    fs::create_directories(dir_);
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
    EngineTest::TearDown();
  }
  std::string write(const std::string& name, const std::vector<uint8_t>& bytes) {
    std::string path = (dir_ / name).string();
    writeFile(path, bytes);
    return path;
  }
  std::string write(const std::string& name, const json& header, const std::vector<uint8_t>& data) {
    return write(name, packFile(header.dump(), data));
  }
  // Opening `path` must throw spar::Error with one line naming the file and containing `phrase`.
  void expectRefused(const std::string& path, const std::string& phrase) {
    SCOPED_TRACE(path);
    try {
      PackedModel::open(path);
      ADD_FAILURE() << "opened without error; expected: " << phrase;
    } catch (const Error& e) {
      const std::string msg = e.what();
      std::cout << "  refused: " << msg << "\n";
      EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
      EXPECT_EQ(msg.rfind(path + ": ", 0), 0u) << msg;
      EXPECT_NE(msg.find(phrase), std::string::npos) << "message lacks '" << phrase << "': " << msg;
    }
  }

  fs::path dir_;
};

// ---- the tiny model made by the converter ----

TEST_F(PackedModelTest, HeaderAndConfig) {
  PackedModel m = PackedModel::open(kTiny);
  EXPECT_EQ(m.metadata().at("format"), "spar-vulkan");
  EXPECT_EQ(m.metadata().at("format_version"), "1");
  ASSERT_TRUE(m.config().is_object());
  EXPECT_EQ(m.config().at("d").get<int>(), 64);
  EXPECT_EQ(m.config().at("scene_tokens").get<int>(), 16);
  EXPECT_TRUE(m.config().at("dino").is_object());
  EXPECT_TRUE(m.components().at("spar").get<bool>());
  EXPECT_GT(m.names().size(), 100u);
  EXPECT_TRUE(m.has("scene_code"));
  EXPECT_FALSE(m.has("no.such.tensor"));
  const auto& sc = m.info("scene_code");
  EXPECT_EQ(sc.dtype, FileDType::F32);
  EXPECT_EQ(sc.shape, (Shape{16, 64}));
  EXPECT_EQ(sc.bytes(), 16u * 64 * 4);
  // names() are in data order.
  for (size_t i = 1; i < m.names().size(); ++i) EXPECT_LE(m.info(m.names()[i - 1]).end, m.info(m.names()[i]).begin);
  EXPECT_THROW(m.info("no.such.tensor"), Error);
}

// Found by tests/fuzz/spar_reader_fuzz: dino mean / std are stored as floats, and a value beyond
// float's range (3.5e38) became infinite and was accepted.
TEST_F(PackedModelTest, ConfigValuesBeyondFloatRangeAreRefused) {
  const PackedModel m = PackedModel::open(kTiny);
  EXPECT_NO_THROW(SparConfig::fromJson(m.config(), m.path()));
  for (const char* field : {"mean", "std"}) {
    json c = m.config();
    c["dino"][field][0] = 3.5e38;
    try {
      SparConfig::fromJson(c, m.path());
      ADD_FAILURE() << "dino." << field << "[0] = 3.5e38 was accepted";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(std::string("'") + field + "' is not a list of 3 finite"), std::string::npos)
          << e.what();
    }
  }
}

TEST_F(PackedModelTest, UploadEqualsFileBytes) {
  PackedModel m = PackedModel::open(kTiny);
  const std::vector<uint8_t> file = readFile(kTiny);
  uint64_t headerLen;
  std::memcpy(&headerLen, file.data(), 8);
  for (const std::string name : {"scene_code", "transformer_encoder.0.attn.to_qkv.weight"}) {
    SCOPED_TRACE(name);
    const auto& info = m.info(name);
    Tensor t = m.upload(eng(), name, DType::F32);
    EXPECT_EQ(t.dtype(), DType::F32);
    EXPECT_EQ(t.shape(), info.shape);
    std::vector<uint8_t> device(t.bytes());
    eng().read(t, device.data(), device.size());
    // The file's bytes, read without the mapping.
    const uint8_t* expected = file.data() + 8 + headerLen + info.begin;
    ASSERT_EQ(device.size(), info.bytes());
    EXPECT_EQ(std::memcmp(device.data(), expected, device.size()), 0);
    // Not a trivially constant tensor.
    std::vector<float> v = eng().download(t);
    EXPECT_NE(v.front(), v.back());
  }
  EXPECT_EQ(m.upload(eng(), "transformer_encoder.0.attn.to_qkv.weight", DType::F32).shape(), (Shape{192, 64}));
}

TEST_F(PackedModelTest, UploadAsHalf) {
  PackedModel m = PackedModel::open(kTiny);
  const std::string name = "transformer_encoder.0.attn.to_qkv.weight";
  Tensor t = m.upload(eng(), name, DType::F16);
  EXPECT_EQ(t.dtype(), DType::F16);
  EXPECT_EQ(t.shape(), (Shape{192, 64}));
  const std::vector<float> expected = roundToHalf(m.floats(name));
  const std::vector<float> got = eng().download(t);
  ASSERT_EQ(got.size(), expected.size());
  EXPECT_EQ(std::memcmp(got.data(), expected.data(), got.size() * 4), 0);
}

TEST_F(PackedModelTest, WeightSetLoadsOnlyWhatIsRequired) {
  PackedModel m = PackedModel::open(kTiny);
  WeightSet w(eng(), m);
  EXPECT_EQ(w.count(), 0u);
  EXPECT_EQ(w.bytesLoaded(), 0u);
  const Tensor& a = w.require("scene_code", {16, 64});
  EXPECT_EQ(a.shape(), (Shape{16, 64}));
  const Tensor& b = w.require("scene_code", {-1, 64});  // cached: the same buffer
  EXPECT_EQ(a.bufferPtr(), b.bufferPtr());
  EXPECT_EQ(w.count(), 1u);
  EXPECT_EQ(w.bytesLoaded(), 16u * 64 * 4);
  w.require("transformer_encoder.0.attn.to_qkv.weight", {192, 64}, DType::F16);
  EXPECT_EQ(w.count(), 2u);
  EXPECT_EQ(w.bytesLoaded(), 16u * 64 * 4 + 192u * 64 * 2);
  ASSERT_EQ(w.loaded().size(), 2u);
  EXPECT_EQ(w.loaded()[1].first, "transformer_encoder.0.attn.to_qkv.weight");
  EXPECT_EQ(w.loaded()[1].second, DType::F16);
  EXPECT_FALSE(w.optional("mask_token_that_is_not_there", {1, 1, 64}).defined());
  EXPECT_EQ(w.count(), 2u);

  auto expectError = [&](auto&& f, const std::string& name, const std::string& phrase) {
    try {
      f();
      ADD_FAILURE() << "no error for " << name;
    } catch (const Error& e) {
      const std::string msg = e.what();
      std::cout << "  refused: " << msg << "\n";
      EXPECT_EQ(msg.find('\n'), std::string::npos) << msg;
      EXPECT_NE(msg.find("'" + name + "'"), std::string::npos) << msg;
      EXPECT_NE(msg.find(phrase), std::string::npos) << msg;
    }
  };
  expectError([&] { w.require("scene_code", {64, 16}); }, "scene_code", "has shape [16, 64], expected [64, 16]");
  expectError([&] { w.require("scene_code", {16, 64, 1}); }, "scene_code", "expected [16, 64, 1]");
  expectError([&] { w.require("transformer_encoder.9.attn.to_qkv.weight", {192, 64}); },
              "transformer_encoder.9.attn.to_qkv.weight", "missing");
  EXPECT_EQ(w.count(), 2u);
  w.clear();
  EXPECT_EQ(w.count(), 0u);
  EXPECT_EQ(w.bytesLoaded(), 0u);
}

// requirePadded (a layout a layer chooses, engine/ops/row_padding.h): the stored values at the
// start of each padded row, zeros after them and in the added rows; only the padded tensor is
// uploaded; one tensor cannot be on the device both ways; fp16 matrices keep their rounding; a
// matrix quantized at upload is not padded (undefined, nothing loaded).
TEST_F(PackedModelTest, WeightSetPadsOnRequest) {
  PackedModel m = PackedModel::open(kTiny);
  const std::string mlp2 = "transformer_encoder.0.mlp.mlp.2.weight", norm = "transformer_encoder.0.norm1.weight";
  WeightSet plain(eng(), m), padded(eng(), m);
  const std::vector<float> stored = eng().download(plain.require(mlp2, {64, 256}));
  const Tensor& t = padded.requirePadded(mlp2, {64, 256}, {66, 260});
  ASSERT_TRUE(t.defined());
  EXPECT_EQ(t.shape(), (Shape{66, 260}));
  EXPECT_EQ(t.dtype(), DType::F32);
  const std::vector<float> got = eng().download(t);
  for (int64_t r = 0; r < 66; ++r)
    for (int64_t c = 0; c < 260; ++c)
      ASSERT_EQ(got[r * 260 + c], r < 64 && c < 256 ? stored[r * 256 + c] : 0.0f) << r << ", " << c;
  EXPECT_EQ(padded.bytesLoaded(), 66u * 260 * 4);
  ASSERT_EQ(padded.loaded().size(), 1u);
  EXPECT_EQ(padded.loaded()[0].first, mlp2);
  EXPECT_EQ(padded.requirePadded(mlp2, {64, 256}, {66, 260}).bufferPtr(), t.bufferPtr());  // cached
  const Tensor v = padded.requirePadded(norm, {64}, {68});
  const std::vector<float> normStored = eng().download(plain.require(norm, {64})), normGot = eng().download(v);
  for (int64_t i = 0; i < 68; ++i) EXPECT_EQ(normGot[i], i < 64 ? normStored[i] : 0.0f) << i;

  auto expectRefused = [](auto&& f, const std::string& phrase) {
    try {
      f();
      ADD_FAILURE() << "no error for " << phrase;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(phrase), std::string::npos) << e.what();
    }
  };
  expectRefused([&] { padded.require(mlp2, {64, 256}); }, "is on the device padded to [66, 260]; asked for as stored too");
  expectRefused([&] { padded.requirePadded(mlp2, {64, 256}, {64, 264}); }, "asked for padded to [64, 264] too");
  expectRefused([&] { plain.requirePadded(mlp2, {64, 256}, {64, 260}); }, "is on the device as [64, 256]");
  expectRefused([&] { padded.requirePadded(norm, {64}, {60}); }, "cannot be padded to [60]");
  expectRefused([&] { padded.requirePadded(norm, {64}, {64, 4}); }, "cannot be padded to [64, 4]");
  expectRefused([&] { padded.requirePadded(mlp2, {64, 255}, {64, 260}); }, "expected [64, 255]");
  EXPECT_EQ(padded.count(), 2u);

  if (eng().caps().supportsFp16Storage()) {
    WeightSet half(eng(), m, DType::F16), halfPadded(eng(), m, DType::F16);
    const std::vector<float> h = eng().download(half.require(mlp2, {64, 256}));
    const Tensor& hp = halfPadded.requirePadded(mlp2, {64, 256}, {64, 260});
    EXPECT_EQ(hp.dtype(), DType::F16);
    const std::vector<float> hg = eng().download(hp);
    for (int64_t r = 0; r < 64; ++r)
      for (int64_t c = 0; c < 260; ++c) ASSERT_EQ(hg[r * 260 + c], c < 256 ? h[r * 256 + c] : 0.0f) << r << ", " << c;
  }
  WeightSet q8(eng(), m, DType::Q8);
  EXPECT_FALSE(q8.requirePadded(mlp2, {64, 256}, {64, 260}).defined());
  EXPECT_EQ(q8.count(), 0u);
}

TEST_F(PackedModelTest, TruncatedCopyIsRefused) {
  // Truncated anywhere past the header: the last tensors' data lie outside the file.
  const std::vector<uint8_t> file = readFile(kTiny);
  const fs::path dir = fs::temp_directory_path() / ("spar_packed_trunc_" + std::to_string(getpid()));
  fs::create_directories(dir);
  const std::string path = (dir / "truncated.spar").string();
  for (size_t keep : {file.size() - 1, file.size() / 2, size_t{100}, size_t{7}, size_t{0}}) {
    SCOPED_TRACE(keep);
    writeFile(path, std::vector<uint8_t>(file.begin(), file.begin() + static_cast<std::ptrdiff_t>(keep)));
    try {
      PackedModel::open(path);
      ADD_FAILURE() << "truncated to " << keep << " bytes and opened";
    } catch (const Error& e) {
      std::cout << "  refused: " << e.what() << "\n";
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos);
      EXPECT_EQ(std::string(e.what()).rfind(path + ": ", 0), 0u);
    }
  }
  fs::remove_all(dir);
}

// ---- hand-made files ----

TEST_F(HandMadeFileTest, ValidFileAllDtypes) {
  std::vector<uint8_t> data;
  json h;
  h["__metadata__"] = goodMetadata();
  h["__metadata__"]["components"] = R"({"spar": true})";
  const std::vector<float> f32 = {1.5f, -2.0f, 1e6f, -1e6f, 0.0f, 3.25f};
  std::vector<uint16_t> f16;
  const std::vector<float> f16src = {0.5f, -1.25f, 65504.0f, 1e-3f};
  for (float x : f16src) f16.push_back(floatToHalf(x));
  const std::vector<int64_t> i64 = {0, -5, 7, 2147483647, -2147483648LL};
  const std::vector<int32_t> i32 = {1, -2, 3};
  const std::vector<uint8_t> u8 = {1, 2, 3};
  auto add = [&](const std::string& name, const char* dtype, Shape shape, auto values) {
    uint64_t begin = data.size();
    append(data, values);
    h[name] = {{"dtype", dtype}, {"shape", shape}, {"data_offsets", {begin, data.size()}}};
  };
  add("u8", "U8", {3}, u8);  // leaves the following tensors unaligned
  add("f32", "F32", {2, 3}, f32);
  add("f16", "F16", {4}, f16);
  add("i64", "I64", {5}, i64);
  add("i32", "I32", {1, 3}, i32);
  add("scalar", "F32", {}, std::vector<float>{42.0f});
  add("empty", "F32", {0, 4}, std::vector<float>{});
  const std::string path = write("valid.spar", h, data);

  PackedModel m = PackedModel::open(path);
  EXPECT_EQ(m.config().at("d").get<int>(), 8);
  EXPECT_EQ(m.names(), (std::vector<std::string>{"u8", "f32", "f16", "i64", "i32", "scalar", "empty"}));
  EXPECT_EQ(m.info("u8").dtype, FileDType::U8);
  EXPECT_EQ(std::vector<uint8_t>(m.data("u8").begin(), m.data("u8").end()), u8);

  EXPECT_EQ(eng().download(m.upload(eng(), "f32", DType::F32)), f32);
  // F32 -> F16 saturates at 65504 (1e6 stays finite).
  std::vector<float> halfOf = eng().download(m.upload(eng(), "f32", DType::F16));
  EXPECT_EQ(halfOf, (std::vector<float>{1.5f, -2.0f, 65504.0f, -65504.0f, 0.0f, 3.25f}));
  // F16 -> F16 and F16 -> F32.
  const std::vector<float> f16values = roundToHalf(f16src);
  EXPECT_EQ(eng().download(m.upload(eng(), "f16", DType::F16)), f16values);
  Tensor f16as32 = m.upload(eng(), "f16", DType::F32);
  EXPECT_EQ(f16as32.dtype(), DType::F32);
  EXPECT_EQ(eng().download(f16as32), f16values);
  EXPECT_EQ(m.floats("f16"), f16values);
  // Integers.
  Tensor i64as32 = m.upload(eng(), "i64", DType::I32);
  std::vector<int32_t> ints(5);
  eng().read(i64as32, ints.data(), 20);
  EXPECT_EQ(ints, (std::vector<int32_t>{0, -5, 7, 2147483647, -2147483647 - 1}));
  Tensor i32t = m.upload(eng(), "i32", DType::I32);
  EXPECT_EQ(i32t.shape(), (Shape{1, 3}));
  EXPECT_EQ(eng().download(i32t), (std::vector<float>{1, -2, 3}));
  EXPECT_EQ(eng().download(m.upload(eng(), "scalar", DType::F32)), std::vector<float>{42.0f});
  EXPECT_EQ(m.upload(eng(), "empty", DType::F16).numel(), 0);

  // Refused conversions: one line naming the tensor and both types.
  auto expectRefusal = [&](const std::string& name, DType want, const std::string& phrase) {
    try {
      m.upload(eng(), name, want);
      ADD_FAILURE() << name << " uploaded as " << dtypeName(want);
    } catch (const Error& e) {
      const std::string msg = e.what();
      std::cout << "  refused: " << msg << "\n";
      EXPECT_EQ(msg.find('\n'), std::string::npos);
      EXPECT_NE(msg.find("'" + name + "'"), std::string::npos) << msg;
      EXPECT_NE(msg.find(phrase), std::string::npos) << msg;
    }
  };
  expectRefusal("i64", DType::F32, "I64 [5]: cannot upload it as f32");
  expectRefusal("i32", DType::F16, "cannot upload it as f16");
  expectRefusal("f32", DType::I32, "cannot upload it as i32");
  expectRefusal("u8", DType::F32, "cannot upload it as f32");
  EXPECT_THROW(m.naturalDType("u8"), Error);
  EXPECT_THROW(m.floats("i32"), Error);

  WeightSet w(eng(), m);
  EXPECT_EQ(w.require("f16", {4}).dtype(), DType::F16);
  EXPECT_EQ(w.require("i64", {5}).dtype(), DType::I32);
  EXPECT_EQ(w.bytesLoaded(), 4u * 2 + 5u * 4);
}

TEST_F(HandMadeFileTest, I64OutOfRangeIsRefused) {
  std::vector<uint8_t> data;
  append(data, std::vector<int64_t>{1, 1LL << 40});
  json h;
  h["__metadata__"] = goodMetadata();
  h["ids"] = {{"dtype", "I64"}, {"shape", {2}}, {"data_offsets", {0, 16}}};
  PackedModel m = PackedModel::open(write("i64.spar", h, data));
  try {
    m.upload(eng(), "ids", DType::I32);
    ADD_FAILURE() << "2^40 uploaded as i32";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("'ids' element 1 = 1099511627776 does not fit i32"), std::string::npos)
        << e.what();
  }
}

TEST_F(HandMadeFileTest, CorruptFilesAreRefused) {
  const std::vector<uint8_t> data(64, 0);
  auto header = [&](json tensors, json meta = goodMetadata()) {
    tensors["__metadata__"] = meta;
    return tensors;
  };
  auto tensor = [](const char* dtype, Shape shape, uint64_t a, uint64_t b) {
    return json{{"dtype", dtype}, {"shape", shape}, {"data_offsets", {a, b}}};
  };

  expectRefused(write("empty.spar", std::vector<uint8_t>{}), "too short");
  expectRefused(write("short.spar", std::vector<uint8_t>{1, 2, 3, 4, 5}), "too short");
  expectRefused(write("headerlen.spar", packFile(header({}).dump(), data, 100000)), "header length 100000 runs past");
  expectRefused(write("headerlen_huge.spar", packFile(header({}).dump(), data, std::numeric_limits<uint64_t>::max())),
                "runs past the end of the file");
  expectRefused(write("badjson.spar", packFile("{\"__metadata__\": {\"format\":\n", data)), "not valid JSON");
  expectRefused(write("binary.spar", packFile(std::string("\x01\x02\xff\n\x00 ", 6), data)), "not valid JSON");
  expectRefused(write("array.spar", packFile("[1, 2]", data)), "not a JSON object");
  expectRefused(write("nometa.spar", json{{"x", tensor("F32", {1}, 0, 4)}}, data), "no __metadata__");
  json meta = goodMetadata();
  meta["format"] = "safetensors-other";
  expectRefused(write("format.spar", header({}, meta), data), "format 'safetensors-other' is not 'spar-vulkan'");
  meta = goodMetadata();
  meta.erase("format");
  expectRefused(write("noformat.spar", header({}, meta), data), "no 'format'");
  meta = goodMetadata();
  meta["format_version"] = "3";
  expectRefused(write("version.spar", header({}, meta), data), "unsupported format_version '3'");
  meta["format_version"] = "2";
  expectRefused(write("version2.spar", header({}, meta), data), "format_version '2' without __metadata__ quantized");
  meta = goodMetadata();
  meta["format_version"] = 1;
  expectRefused(write("version_int.spar", header({}, meta), data), "'format_version' is not a string");
  meta = goodMetadata();
  meta["config"] = "{d: 8";
  expectRefused(write("config.spar", header({}, meta), data), "config is not valid JSON");
  meta["config"] = "[8]";
  expectRefused(write("config_array.spar", header({}, meta), data), "config is not a JSON object");
  meta.erase("config");
  expectRefused(write("noconfig.spar", header({}, meta), data), "no 'config'");

  expectRefused(write("dtype.spar", header({{"w", tensor("BF16", {2}, 0, 4)}}), data), "tensor 'w': unsupported dtype 'BF16'");
  expectRefused(write("outside.spar", header({{"w", tensor("F32", {4, 4}, 0, 64)}, {"x", tensor("F32", {2}, 60, 68)}}), data),
                "tensor 'x' data [60, 68) lies outside the file");
  expectRefused(write("outside_far.spar", header({{"x", tensor("U8", {1}, (1ull << 62), (1ull << 62) + 1)}}), data),
                "lies outside the file");
  expectRefused(write("reversed.spar", header({{"x", tensor("F32", {0}, 8, 4)}}), data), "end before they begin");
  expectRefused(write("overlap.spar", header({{"a", tensor("F32", {4}, 0, 16)}, {"b", tensor("F32", {4}, 12, 28)}}), data),
                "tensors 'a' [0, 16) and 'b' [12, 28) overlap");
  expectRefused(write("contained.spar",
                      header({{"a", tensor("F32", {8}, 0, 32)}, {"b", tensor("F32", {2}, 40, 48)}, {"c", tensor("F32", {2}, 36, 44)}}),
                      data),
                "overlap");
  expectRefused(write("inside.spar", header({{"a", tensor("F32", {8}, 0, 32)}, {"b", tensor("F16", {2}, 8, 12)}}), data),
                "overlap");
  expectRefused(write("mismatch.spar", header({{"w", tensor("F32", {3, 3}, 0, 32)}}), data),
                "tensor 'w': F32 [3, 3] needs 36 bytes but data_offsets [0, 32) span 32");
  expectRefused(write("mismatch16.spar", header({{"w", tensor("F16", {4}, 0, 16)}}), data), "needs 8 bytes");
  expectRefused(write("huge_shape.spar", header({{"w", tensor("F32", {1ull << 40, 1ull << 40}, 0, 16)}}), data), "too large");
  expectRefused(write("neg_shape.spar", packFile(R"({"__metadata__": )" + goodMetadata().dump() +
                                                     R"(, "w": {"dtype": "F32", "shape": [-1, 4], "data_offsets": [0, 16]}})",
                                                 data)),
                "not a list of non-negative integers");
  expectRefused(write("float_shape.spar", header({{"w", {{"dtype", "F32"}, {"shape", {1.5}}, {"data_offsets", {0, 4}}}}}), data),
                "not a list of non-negative integers");
  expectRefused(write("no_offsets.spar", header({{"w", {{"dtype", "F32"}, {"shape", {1}}}}}), data),
                "data_offsets is not a pair");
  expectRefused(write("entry.spar", header({{"w", 5}}), data), "tensor 'w': entry is not a JSON object");
  expectRefused(write("newline_name.spar", header({{"bad\nname", tensor("X", {1}, 0, 4)}}), data), "unsupported dtype");
  expectRefused((dir_ / "does_not_exist.spar").string(), "cannot open");
  expectRefused(dir_.string(), "not a regular file");
}

// Quantized matrices (format version 2, converter/FORMAT.md "Quantized matrices"): a q8 and a
// q4 matrix read back as code * scale, uploaded as rows of codes then scales, refused as f32;
// every inconsistent record refused in one line naming the matrix.
TEST_F(HandMadeFileTest, QuantizedMatricesAreReadAndBadRecordsRefused) {
  auto file = [&](json records, std::vector<float> wScales = {0.5f, 0.25f}, json version = "2") {
    std::vector<uint8_t> data;
    json h;
    h["__metadata__"] = goodMetadata();
    h["__metadata__"]["format_version"] = version;
    if (!records.is_null()) h["__metadata__"]["quantized"] = records.dump();
    auto add = [&](const std::string& name, const char* dtype, Shape shape, const auto& values) {
      const uint64_t begin = data.size();
      append(data, values);
      h[name] = {{"dtype", dtype}, {"shape", shape}, {"data_offsets", {begin, data.size()}}};
    };
    std::vector<int8_t> w(64);
    for (int i = 0; i < 64; ++i) w[size_t(i)] = int8_t(i % 2 ? -i : i);
    add("w", "I8", {2, 32}, w);
    add("w.qscale", "F32", {2, 1}, wScales);
    add("v", "U8", {1, 32}, std::vector<uint8_t>(32, 0x1F));  // codes 15 - 8 = 7 (even k), 1 - 8 = -7 (odd k)
    add("v.qscale", "F32", {1, 2}, std::vector<float>{1.0f, 2.0f});
    return packFile(h.dump(), data);
  };
  const json good = {{"w", {{"bits", 8}, {"block", 32}, {"shape", {2, 32}}}},
                     {"v", {{"bits", 4}, {"block", 32}, {"shape", {1, 64}}}}};
  const std::string path = write("quantized.spar", file(good));
  {
    PackedModel m = PackedModel::open(path);
    EXPECT_EQ(m.info("w").shape, (Shape{2, 32}));
    EXPECT_EQ(m.info("w").quantBits, 8);
    EXPECT_EQ(m.naturalDType("w"), DType::Q8);
    EXPECT_EQ(m.naturalDType("v"), DType::Q4);
    const std::vector<float> w = m.floats("w");
    EXPECT_EQ(w[3], -3 * 0.5f);
    EXPECT_EQ(w[32 + 4], 36 * 0.25f);
    const std::vector<float> v = m.floats("v");
    EXPECT_EQ(v[0], 7.0f);
    EXPECT_EQ(v[33], -14.0f);
    Tensor t = m.upload(eng(), "w", DType::Q8);
    EXPECT_EQ(t.dtype(), DType::Q8);
    EXPECT_EQ(t.bytes(), 2u * 36u);
    EXPECT_EQ(m.upload(eng(), "v", DType::Q4).bytes(), 40u);
    try {
      m.upload(eng(), "w", DType::F32);
      ADD_FAILURE() << "a q8 matrix uploaded as f32";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("reach only the kernels that dequantize them"), std::string::npos) << e.what();
    }
  }
  auto with = [&](const char* name, const char* key, json value) {
    json r = good;
    if (value.is_null()) r[name].erase(key);
    else r[name][key] = value;
    return r;
  };
  expectRefused(write("q_bits.spar", file(with("w", "bits", 5))), "quantized tensor 'w': bit width 5");
  expectRefused(write("q_block.spar", file(with("w", "block", 16))), "block of 16 values");
  expectRefused(write("q_noshape.spar", file(with("w", "shape", nullptr))), "no 'shape'");
  expectRefused(write("q_shape3.spar", file(with("w", "shape", {1, 2, 32}))), "is not [N, K]");
  expectRefused(write("q_partial.spar", file(with("w", "shape", {4, 16}))), "not whole blocks of 32");
  expectRefused(write("q_partial4.spar", file(with("w", "shape", {2, 4, 2, 2}))), "rows of 16 values are not whole blocks");
  // A convolution kernel [Cout, Cin, kh, kw] is quantized as the matrix [Cout, Cin*kh*kw]: its
  // own shape kept, uploaded as that matrix.
  {
    PackedModel m = PackedModel::open(write("q_conv.spar", file(with("w", "shape", {2, 8, 2, 2}))));
    EXPECT_EQ(m.info("w").shape, (Shape{2, 8, 2, 2}));
    EXPECT_EQ(m.floats("w")[32 + 4], 36 * 0.25f);
    const Tensor t = m.upload(eng(), "w", DType::Q8);
    EXPECT_EQ(t.shape(), (Shape{2, 32}));
    EXPECT_EQ(t.bytes(), 2u * 36u);
  }
  expectRefused(write("q_bitsdtype.spar", file(with("w", "bits", 4))), "codes are I8 [2, 32], 4-bit codes");
  expectRefused(write("q_count.spar", file(with("v", "shape", {2, 32}))), "codes are U8 [1, 32]");
  json missing = good;
  missing["x"] = good["w"];
  expectRefused(write("q_missing.spar", file(missing)), "quantized tensor 'x': no tensor of its codes");
  json scaleShape = good;
  scaleShape["v.qscale"] = {{"bits", 8}, {"block", 32}, {"shape", {1, 64}}};  // the scales named as a matrix
  expectRefused(write("q_scalerecord.spar", file(scaleShape)), "quantized tensor 'v.qscale'");
  expectRefused(write("q_v1.spar", file(good, {0.5f, 0.25f}, "1")), "__metadata__ quantized in a format_version '1'");
  expectRefused(write("q_notobject.spar", file(json("["))), "quantized is not a JSON object");
  // A scale that is not a finite non-negative float, or too large for its codes: refused when
// the matrix is read.
  // (and one whose largest code times it would not be a finite float: 128 * 3e38)
  for (float bad : {std::nanf(""), std::numeric_limits<float>::infinity(), -1.0f, 3e38f}) {
    PackedModel m = PackedModel::open(write("q_scale.spar", file(good, {0.5f, bad})));
    try {
      m.upload(eng(), "w", DType::Q8);
      ADD_FAILURE() << "scale " << bad << " accepted";
    } catch (const Error& e) {
      const std::string msg = e.what();
      std::cout << "  refused: " << msg << "\n";
      EXPECT_NE(msg.find("quantized tensor 'w': block 1 has the scale"), std::string::npos) << msg;
    }
  }
}

// The model card (__metadata__.model_card, model/model_card.h): read and made into the sentence
// `spar render` prints; a card that is not what the converter writes is refused by field.
TEST_F(HandMadeFileTest, ModelCardIsReadAndABadOneRefusedByField) {
  const std::vector<uint8_t> data;
  auto withCard = [&](const std::string& card) {
    json h;
    h["__metadata__"] = goodMetadata();
    h["__metadata__"]["model_card"] = card;
    return h;
  };
  const json good = {{"kind", "demonstration"},
                     {"about", "trained here, it renders grey"},
                     {"measured",
                      {{"what", "held-out K=3"}, {"psnr_db", 18.14}, {"baseline", "copying the nearest input"},
                       {"baseline_psnr_db", 20.02}}}};
  const PackedModel m = PackedModel::open(write("card.spar", withCard(good.dump()), data));
  ASSERT_TRUE(m.modelCard().has_value());
  EXPECT_EQ(modelCardSentence(*m.modelCard()),
            "Demonstration model: trained here, it renders grey (held-out K=3 PSNR 18.1 dB, below the 20.0 dB of copying "
            "the nearest input); for real photos, convert the official checkpoint (docs/checkpoints.md).");
  json above = good;
  above["measured"]["psnr_db"] = 25.0;
  above.erase("about");
  above["about"] = "fitted to three rooms";
  EXPECT_NE(modelCardClaim(parseModelCard(above.dump())).find("PSNR 25.0 dB, above the 20.0 dB"), std::string::npos);
  json trained = good;
  trained["training"] = {{"data", "takes of three rooms"}, {"steps", 2400}, {"minutes", 80.5}};
  const ModelCard t = parseModelCard(trained.dump());
  EXPECT_TRUE(t.trained);
  EXPECT_EQ(t.trainingData, "takes of three rooms");
  EXPECT_EQ(t.trainingSteps, 2400);
  EXPECT_DOUBLE_EQ(t.trainingMinutes, 80.5);
  EXPECT_FALSE(parseModelCard(good.dump()).trained);
  json bare = {{"kind", "demonstration"}, {"about", "made by hand"}};
  EXPECT_EQ(modelCardClaim(parseModelCard(bare.dump())), "Demonstration model: made by hand");
  EXPECT_FALSE(PackedModel::open(write("nocard.spar", json{{"__metadata__", goodMetadata()}}, data)).modelCard());

  json bad = good;
  bad["kind"] = "official";
  expectRefused(write("card_kind.spar", withCard(bad.dump()), data), "model_card: unknown kind 'official'");
  bad = good;
  bad["colour"] = "red";
  expectRefused(write("card_field.spar", withCard(bad.dump()), data), "model_card: unknown field 'colour'");
  bad = good;
  bad["about"] = "two\nlines";
  expectRefused(write("card_about.spar", withCard(bad.dump()), data), "model_card: about must be a non-empty one-line");
  bad = good;
  bad["measured"]["psnr_db"] = "high";
  expectRefused(write("card_psnr.spar", withCard(bad.dump()), data), "model_card: measured.psnr_db must be a finite number");
  bad = good;
  bad["measured"].erase("baseline");
  expectRefused(write("card_measured.spar", withCard(bad.dump()), data), "model_card: measured must hold exactly");
  expectRefused(write("card_json.spar", withCard("{kind"), data), "model_card: not a JSON object");
  bad = trained;
  bad["training"]["steps"] = 0;
  expectRefused(write("card_steps.spar", withCard(bad.dump()), data), "model_card: training.steps must be a positive integer");
  bad = trained;
  bad["training"].erase("minutes");
  expectRefused(write("card_training.spar", withCard(bad.dump()), data), "model_card: training must hold exactly");
}

}  // namespace
}  // namespace spar::test
