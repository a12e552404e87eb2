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
};

// What encoding a request leaves on the host.
struct Encoded {
  std::vector<float> c2w;          // [V, 4, 4] estimated, OpenCV, canonical frame
  std::vector<float> fxfycxcy;     // [V, 4] normalized intrinsics
  std::vector<float> motionInput;  // [K, H, W] P(dynamic) of the input views (empty if assumeStatic)
  std::vector<float> motionTarget; // [T, H, W] with targetMotion (else empty)
  int64_t canonicalIndex = 0;
};

// GPU time of one stage (its dispatches' timestamps: compute only), the time the driver spent
// building kernels for it (compiles at first dispatch; 0 once they are in its cache, and on
// drivers that compile at pipeline creation), and host wall time around it (which includes
// both and pipeline creation).
struct StageTime {
  std::string name;
  double gpuMs = 0, wallMs = 0, buildMs = 0;
};

}  // namespace spar
