// What a SPAR request asks for and what it gives back (the types of spar/session.h). Images
// and outputs are plain float arrays, row-major, channels first.
//
// Cameras: camera-to-world 4x4 in OpenCV axes (x right, y down, z forward) in the canonical
// view's frame (the first input view unless the model says otherwise), intrinsics normalized
// by the image size: fx/W, fy/H, cx/W, cy/H.
#pragma once
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "spar/export.h"

namespace spar {

// One ordered sequence of frames (capture order); inputs and targets are positions in it.
struct SPAR_API ViewPlan {
  int64_t views = 0;
  std::vector<int64_t> inputs;   // increasing, at least 1
  std::vector<int64_t> targets;  // increasing, disjoint from inputs (may be empty)
  // Throws spar::Error (one line) if the plan is inconsistent.
  void validate() const;
};

// Cameras to render instead of the estimated targets (row-major c2w, normalized intrinsics).
struct RenderCameras {
  std::vector<std::array<float, 16>> c2w;
  std::vector<std::array<float, 4>> fxfycxcy;
  size_t size() const { return c2w.size(); }
};

// Which motion masks gate the input tokens (the official mask_source): CV-DRP's probabilities
// (Raw, the official release's default) or the SAM2.1-refined hard masks (Refined).
enum class MaskSource { Raw, Refined };

struct Request {
  std::vector<float> images;  // [V, 3, H, W] prepared images in [0, 1], sequence order (spar/images.h)
  int64_t height = 0, width = 0;  // 0: the model's image size
  ViewPlan plan;
  // Skip DINOv3 and CV-DRP: every input token is treated as static (no gating at all).
  bool assumeStatic = false;
  // Also run CV-DRP over the target views (evaluation of motion masks on targets).
  bool targetMotion = false;
  // false = CV-DRP still runs and gives masks, but the input tokens are not gated; the same
  // rendering as assumeStatic (the --no-gating ablation of spar eval).
  bool gating = true;
  // Semantic models: run the semantic head when rendering (features for labels or output).
  // Without it the semantic queries still take part in the decoder (the model was trained so).
  bool semanticFeatures = false;
  // Semantic models: precomputed LSeg features of the input views [K, C, H/2, W/2] instead of
  // running the LSeg encoder (tests; features computed elsewhere). Empty: the engine runs LSeg.
  std::vector<float> lsegFeatures;
  // SAM2.1 refinement of the motion masks (a model packed with spar-convert --sam2; else an
  // Error): each input view's P(dynamic) > 0.5 prompts SAM2 on that view's image, giving a hard
  // 0/1 mask (a view with fewer than 10 dynamic pixels, or all but fewer than 10, keeps its
  // thresholded mask and runs nothing); with targetMotion the targets' too. Results in
  // Encoded::refinedInput / refinedTarget / refineViews. Without it no SAM2 weight is uploaded.
  bool refine = false;
  // Refined: the refined masks gate the input tokens (average-pooled per patch, as the official
  // mask_source: refined); implies refine. Not with assumeStatic.
  MaskSource maskSource = MaskSource::Raw;
  // The masks to refine instead of CV-DRP's: P(dynamic) [V, H, W] for every view of the sequence
  // (a caller's own masks; the inputs' rows are used, and the targets' with targetMotion).
  // Empty: CV-DRP's. Needs refine (or maskSource Refined).
  std::vector<float> refinePrompts;
};

// One view's SAM2.1 refinement (Encoded::refineViews).
struct RefinedView {
  int64_t view = 0;            // position in the sequence
  bool skipped = false;        // too few or too many dynamic pixels: the thresholded mask kept
  int64_t dynamicPixels = 0;   // P(dynamic) > 0.5
  std::array<float, 3> iou{};  // SAM2's IoU predictions of its three masks (not skipped)
  int chosen = -1;             // the mask of the highest IoU, the first of equal ones (not skipped)
  std::vector<float> logits;   // the chosen mask's 256 x 256 logits (not skipped): > 0 is the mask
};

// What encoding a request leaves on the host.
struct Encoded {
  std::vector<float> c2w;          // [V, 4, 4] estimated, OpenCV, canonical frame
  std::vector<float> fxfycxcy;     // [V, 4] normalized intrinsics
  std::vector<float> motionInput;  // [K, H, W] P(dynamic) of the input views (empty if assumeStatic)
  std::vector<float> motionTarget; // [T, H, W] with targetMotion (else empty)
  // With refine: the refined masks, 0 or 1, in motionInput's / motionTarget's layout (targets
  // with targetMotion), and per refined view (inputs, then targets) what SAM2 decided.
  std::vector<float> refinedInput;
  std::vector<float> refinedTarget;
  std::vector<RefinedView> refineViews;
  int64_t canonicalIndex = 0;
};

// GPU time of one stage (its dispatches' timestamps: compute only), the time the driver spent
// building kernels for it (compiles at first dispatch; 0 once they are in its cache, and on
// drivers that compile at pipeline creation), and host wall time: the time it took to record,
// plus its share (by GPU and build time) of the wait for the submission it shares with the
// other stages of its phase. Device memory: what was in use when its submission ended (weights
// it uploaded and buffers kept for later stages included) and the peak of the run so far.
// What it took in commands: dispatches, the pipeline barriers before them, the submissions the
// host waited for, the transformer blocks among them and the most dispatches one block took.
struct StageTime {
  std::string name;
  double gpuMs = 0, wallMs = 0, buildMs = 0;
  uint64_t deviceBytesAfter = 0, devicePeakBytes = 0;
  uint64_t dispatches = 0, barriers = 0, submits = 0, transformerBlocks = 0, blockDispatches = 0;
};

}  // namespace spar
