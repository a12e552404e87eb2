// Model-level goldens made by tests/python/make_spar_goldens.py (CTest fixture spar_goldens):
// the tiny photometric model and, per case directory, the PyTorch reference's float64 output of
// every stage (reference/spar_reference/goldens.py names: "img_tokens", "c2w", "rgb", ...).
#pragma once
#include <nlohmann/json.hpp>
#include <cstdint>
#include <string>
#include <vector>

#include "formats/npy.h"

namespace spar::test {

// SPAR_GOLDENS_DIR/<rel> (the build's fixture directory; the environment variable of the same
// name replaces it, likewise SPAR_FULL_GOLDENS_DIR and SPAR_SEMANTIC_GOLDENS_DIR below)
std::string goldenPath(const std::string& rel);
// The packed tiny model (SPAR_GOLDENS_DIR/tiny.spar).
std::string tinyModelPath();
// The full-size case (fixture spar_goldens_full): SPAR_FULL_GOLDENS_DIR/<rel>.
std::string fullGoldenPath(const std::string& rel);
// The semantic branch's goldens (fixture spar_goldens_semantic): SPAR_SEMANTIC_GOLDENS_DIR/<rel>
// (tiny_semantic.spar, labels.json, case dirs "semantic" and "semantic_path").
std::string semanticGoldenPath(const std::string& rel);
// The goldens of op- and host-level tests that need no model (fixture op_goldens,
// tests/python/make_op_goldens.py): SPAR_OP_GOLDENS_DIR/<rel> ("image", "path", "camera",
// "block/<case>", "size").
std::string opGoldenPath(const std::string& rel);
// The CLIP BPE merges table the fixtures packed: the repository's copy (text/data/clip/) unless
// the build names another (-DSPAR_CLIP_BPE). Throws when the file is missing: text-side tests
// fail rather than skip.
std::string clipBpePath();

class GoldenCase {
 public:
  // A case directory under SPAR_GOLDENS_DIR ("interleaved", "odd_targets", "path"), or an
  // absolute path.
  explicit GoldenCase(const std::string& name);
  const std::string& dir() const { return dir_; }
  const nlohmann::json& manifest() const { return manifest_; }
  bool has(const std::string& name) const;
  NpyArray array(const std::string& name) const;     // <name>.npy
  std::vector<double> doubles(const std::string& name) const;
  std::vector<float> floats(const std::string& name) const;
  std::vector<int64_t> shape(const std::string& name) const;
  std::vector<int64_t> inputs() const;   // manifest "inputs"
  std::vector<int64_t> targets() const;  // manifest "targets"
  std::vector<std::string> files() const;  // frame files in sequence order

 private:
  std::string name_, dir_;
  nlohmann::json manifest_;
};

}  // namespace spar::test
