// The packed weight file (converter/FORMAT.md: safetensors, `__metadata__` format
// "spar-vulkan", format_version "1", config JSON), memory-mapped read-only. open() checks the
// whole header before any tensor byte is trusted: file size, header length, JSON, format and
// version, every tensor's dtype, shape, byte count and offsets (inside the data area, no two
// overlapping), and the config. Tensors reach the device only when asked for (upload()), so
// what a request does not use is never loaded. Every problem is a spar::Error with one line
// naming the file (and the tensor).
#pragma once
#include <nlohmann/json.hpp>

#include <cstdint>
#include <map>
#include <optional>
#include <span>
#include <string>
#include <unordered_map>
#include <vector>

#include "engine/tensor.h"
#include "model/model_card.h"

namespace spar {

class Engine;

// The element types a packed file may hold (safetensors names).
enum class FileDType { F32, F16, I32, I64, U8, I8 };

const char* fileDTypeName(FileDType t);  // "F32", "F16", "I32", "I64", "U8", "I8"
size_t fileDTypeSize(FileDType t);

struct PackedTensorInfo {
  FileDType dtype = FileDType::F32;
  // The tensor's shape; for a quantized matrix (quantBits 8 or 4) the matrix's [N, K] (or a
  // convolution kernel's [Cout, Cin, kh, kw], quantized as [Cout, K = Cin*kh*kw]), while the
  // entry holds its codes (I8 [N, K] or U8 [N, K / 2]) and `scales` names its F32 [N, K / 32].
  // It uploads as the Q8 / Q4 matrix [N, K] (model/quantized_matrices.h quantizedMatrixShape).
  Shape shape;
  uint64_t begin = 0, end = 0;  // byte range in the data area (after the header)
  int quantBits = 0;
  std::string scales;

  int64_t numel() const { return shapeNumel(shape); }
  uint64_t bytes() const { return end - begin; }
};

class PackedModel {
 public:
  static constexpr const char* kFormat = "spar-vulkan";
  static constexpr const char* kFormatVersion = "1";
  // Files with quantized matrices (`__metadata__.quantized`, converter/FORMAT.md).
  static constexpr const char* kQuantFormatVersion = "2";

  // Maps and validates the file; throws spar::Error("<path>: <problem>") on anything wrong.
  static PackedModel open(const std::string& path);
  // The same checks on a file's bytes held in memory (copied into the object); `name` stands for
  // the path in messages. For the fuzz target (tests/fuzz/), which feeds it millions of inputs
  // without a file each.
  static PackedModel fromBytes(std::vector<uint8_t> bytes, const std::string& name);

  PackedModel(PackedModel&& other) noexcept;
  PackedModel& operator=(PackedModel&& other) noexcept;
  PackedModel(const PackedModel&) = delete;
  PackedModel& operator=(const PackedModel&) = delete;
  ~PackedModel();

  const std::string& path() const { return path_; }
  uint64_t fileBytes() const { return size_; }

  // Tensor names in file (data offset) order.
  const std::vector<std::string>& names() const { return names_; }
  bool has(const std::string& name) const { return tensors_.count(name) != 0; }
  // Throws "<path>: no tensor '<name>'" when absent.
  const PackedTensorInfo& info(const std::string& name) const;
  // The tensor's raw little-endian bytes inside the mapping (valid while this object lives;
  // not necessarily aligned to the element size).
  std::span<const uint8_t> data(const std::string& name) const;

  // `__metadata__` as stored (all values strings).
  const std::map<std::string, std::string>& metadata() const { return metadata_; }
  // `__metadata__.config` parsed (a JSON object; SparConfig.to_dict()).
  const nlohmann::json& config() const { return config_; }
  // `__metadata__.components` parsed, or an empty object when the file has none.
  const nlohmann::json& components() const { return components_; }
  // `__metadata__.model_card` parsed (model_card.h: what the model is), when the file has one.
  const std::optional<ModelCard>& modelCard() const { return card_; }

  // The tensor's values as floats on the host (F32/F16, and quantized matrices dequantized). Like
  // upload(), throws for a NaN or infinite value (or scale), naming the tensor and element.
  std::vector<float> floats(const std::string& name) const;
  // Throws spar::Error naming the first NaN or infinite element of a F32/F16 tensor.
  void checkFinite(const std::string& name) const;

  // A new device tensor holding `name`, converted to `want`:
  //   F32 -> F32 / F16 (fp16 saturates at +-65504, like Engine::upload), F16 -> F16 / F32,
  //   I32 -> I32, I64 -> I32 (every value must fit), a quantized matrix -> Q8 / Q4 of its bits
  //   (engine/tensor.h: each row's codes, then its scales). Anything else is refused with an error.
  Tensor upload(Engine& engine, const std::string& name, DType want) const;
  // The engine dtype a tensor uploads as by default: its own (I64 -> I32, a quantized matrix Q8 /
  // Q4); throws for U8 and I8 tensors that are no quantized matrix.
  DType naturalDType(const std::string& name) const;

  // "<path>: <what>", the prefix of every error about this file.
  std::string errorPrefix() const { return path_ + ": "; }

 private:
  PackedModel() = default;
  void unmap();
  // Checks and indexes the header of the bytes [map_, map_ + size_) (open() and fromBytes()).
  void parseHeader();
  void parseMetadata(const nlohmann::json& header);
  void parseTensors(const nlohmann::json& header, uint64_t dataBytes);
  void checkNoOverlap();
  // Checks `__metadata__.quantized` against the tensors it names and marks them (parseHeader).
  void parseQuantized();
  // Throws naming the first scale of a quantized matrix that is negative, NaN or infinite.
  void checkScales(const std::string& name) const;

  std::string path_;
  const uint8_t* map_ = nullptr;  // the mapping, or owned_.data()
  uint64_t size_ = 0;
  std::vector<uint8_t> owned_;  // fromBytes(): the bytes map_ points into (nothing to munmap)
  uint64_t dataStart_ = 0;  // 8 + header length
  std::vector<std::string> names_;
  std::unordered_map<std::string, PackedTensorInfo> tensors_;
  std::map<std::string, std::string> metadata_;
  nlohmann::json config_ = nlohmann::json::object();
  nlohmann::json components_ = nlohmann::json::object();
  std::optional<ModelCard> card_;
};

}  // namespace spar
