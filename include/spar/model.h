// A packed SPAR model (.spar, made by spar-convert; format in converter/FORMAT.md), opened and
// checked: the whole header is validated before any tensor byte is trusted, and weights reach
// the device only when a stage first needs them.
#pragma once
#include <cstdint>
#include <memory>
#include <string>

#include "spar/export.h"

namespace spar {

class SPAR_API Model {
 public:
  // Throws spar::Error (one line, naming the file) for a missing, truncated or malformed file.
  static Model open(const std::string& path);
  ~Model();
  Model(Model&&) noexcept;
  Model& operator=(Model&&) noexcept;

  const std::string& path() const;
  int64_t imageHeight() const;  // the size the model was configured for (what renders default to)
  int64_t imageWidth() const;
  int64_t patchSize() const;    // image sizes must be multiples of it
  bool semantic() const;        // has the semantic branch (features, labels)
  bool hasTokenizer() const;    // carries CLIP's merges table (text prompts)
  // What the model file says it is, when it says it is a demonstration model (its model card,
  // converter/FORMAT.md): one sentence with its measured quality and where the official weights
  // are, which `spar render` prints; "" for any other model.
  std::string demonstrationNote() const;

  struct Impl;
  const Impl& impl() const { return *impl_; }

 private:
  explicit Model(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace spar
