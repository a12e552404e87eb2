// A packed SPAR model (.spar, made by spar-convert; format in converter/FORMAT.md), opened and
// checked: the whole header is validated before any tensor byte is trusted, and weights reach
// the device only when a stage first needs them.
#pragma once
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "spar/export.h"

namespace spar {

// What a demonstration model says of itself (its model card, converter/FORMAT.md), in parts so
// that a page can link the action to the doc.
struct DemonstrationNote {
  std::string claim;   // "Demonstration model: ... (held-out K=3 PSNR 20.6 dB, below the 21.0 dB of ...)"
  std::string when;    // "for real photos, "
  std::string action;  // "convert the official checkpoint"
  std::string doc;     // "docs/checkpoints.md"
  // The whole sentence: claim; when action (doc).
  std::string sentence() const { return claim + "; " + when + action + " (" + doc + ")."; }
};

class SPAR_API Model {
 public:
  // Throws spar::Error (one line, naming the file) for a missing, truncated or malformed file.
  static Model open(const std::string& path);
  ~Model();
  Model(Model&&) noexcept;
  Model& operator=(Model&&) noexcept;

  const std::string& path() const;
  uint64_t fileBytes() const;
  // The configuration as the file stores it (JSON text: converter/FORMAT.md, "config").
  std::string configJson() const;
  int64_t imageHeight() const;  // the size the model was configured for (what renders default to)
  int64_t imageWidth() const;
  int64_t patchSize() const;    // image sizes must be multiples of it
  // How the file stores its weight matrices: "F32", "F16" (a spar-convert --fp16 pack), "I8"
  // (q8 codes) or "U8" (q4 codes), as converter/FORMAT.md names the dtypes.
  std::string matrixStorage() const;
  // "" when the engine runs this model at height x width, else why not (one line): sides
  // multiples of the patch size, and of 32 with the semantic branch (LSeg).
  std::string sizeProblem(int64_t height, int64_t width) const;
  // Views a scene and input views of them the model was trained with, when its configuration
  // says (num_views, num_input_views); 0 when it does not.
  int64_t trainingViews() const;
  int64_t trainingInputViews() const;
  // P(dynamic) above this is a moving pixel (the configuration's mask threshold).
  float maskThreshold() const;
  bool semantic() const;        // has the semantic branch (features, labels)
  int64_t featureChannels() const;  // channels of its semantic features (0 without the branch)
  bool hasTokenizer() const;    // carries CLIP's merges table (text prompts)
  // "" when the model can refine motion masks (packed with spar-convert --sam2), else why not.
  std::string refinementProblem() const;
  // What tokenizing `prompts` would warn about (prompts longer than CLIP's 77 tokens are cut
  // there), without any device work. Throws spar::Error when the model has no tokenizer.
  std::vector<std::string> promptWarnings(const std::vector<std::string>& prompts) const;
  // What the model file says it is, when it says it is a demonstration model (its model card):
  // the sentence `spar render` prints; "" for any other model.
  std::string demonstrationNote() const;
  std::optional<DemonstrationNote> demonstration() const;

  struct Impl;
  const Impl& impl() const { return *impl_; }

 private:
  explicit Model(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace spar
