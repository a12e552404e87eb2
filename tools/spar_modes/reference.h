// The PyTorch reference's fp32 output on the same request: `spar-reference goldens` (not
// `render`, whose PNGs are 8-bit: fp16 weights change pixels by far less than 1/255), run once
// per directory and reused while its inputs stay the same.
#pragma once
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace spar::modes {

struct ReferenceInputs {
  std::string python;       // Debian's python3 (sees python3-torch)
  std::string sourceDir;    // the repository (reference/spar-reference)
  std::string checkpoint;   // X.pt the packed model was made from
  std::string config;       // --config of spar-reference ("" = inferred from the checkpoint)
  std::vector<std::string> frames;
  std::vector<int64_t> inputs;
  std::string sam2, sam2Config;  // the SAM2.1 checkpoint and its variant (refine runs)
  std::string labels;            // comma-separated prompts ("" = no label maps)
  std::string bpe;               // CLIP's BPE merges table (the reference's tokenizer), with labels
};

// Which run of the reference: the whole model, --assume-static, --refine (CV-DRP's masks still
// gate), --mask-source refined.
enum class ReferenceRun { Whole, Static, Refine, RefinedGating };

struct Reference {
  std::string dir;
  bool reused = false;
  std::vector<float> rgb;     // [T, 3, H, W]
  std::vector<float> motion;  // [K, H, W] P(dynamic) of the inputs (empty with assume-static)
  std::vector<float> mask;    // [K, H, W] its binary mask, 0 or 1 (empty with assume-static)
  std::vector<float> refined; // [K, H, W] SAM2.1's refined masks, 0 or 1 (refine runs)
  std::vector<int32_t> labels;  // [T, H, W] label maps of the targets (with prompts)
  double modelMs = 0;         // the reference's own time of the model's stages (no file I/O)
};

// Each run's goldens in its directory (made unless it holds goldens of the same inputs; the
// runs to make in one process); in the order of `runs`. Throws spar::Error.
std::vector<Reference> loadReferences(const ReferenceInputs& inputs,
                                      const std::vector<std::pair<ReferenceRun, std::string>>& runs);

}  // namespace spar::modes
