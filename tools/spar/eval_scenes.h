// The test set of `spar eval` (evaluation/PROTOCOL.md, "Test set", "Views", "Images"):
// scene folders as `scenes/spar-scenes split` writes them, read on the host.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

namespace spar::cli::eval {

struct SceneInfo {
  std::string dir;   // DIR/scene_<seed>
  std::string name;  // scene_<seed>
  int frames = 0, width = 0, height = 0;
  std::vector<std::string> classNames;  // classes.json, in id order
};

// DIR/scene_* folders sorted bytewise (at most maxScenes of them when maxScenes > 0), each with
// its scene.json (n_frames, width, height) and classes.json read. Throws spar::Error naming the
// file for a missing directory, no scenes, or unreadable / inconsistent JSON.
std::vector<SceneInfo> discoverScenes(const std::string& dir, int maxScenes);

// One scene's frames, all at its size.
struct SceneData {
  std::vector<float> rgb;        // [F, 3, H, W] PNG value / 255: the model input and the ground truth
  std::vector<uint8_t> dynamic;  // [F, H, W] mask_XX.png > 127
  std::vector<int32_t> classes;  // [F, H, W] class ids of class_XX.png
};

// Reads rgb_XX.png, mask_XX.png and class_XX.png of every frame. The class maps are
// palette-indexed PNGs whose palette holds the classes' colours (classes.json "color"), and
// the image reader gives the palette's colours: each is mapped back to its class id.
SceneData loadScene(const SceneInfo& scene);

// Input positions for K views of F frames: i_j = floor(j (F - 1) / (K - 1) + 0.5), in integer
// arithmetic (no rounding surprises at exact halves). Requires 2 <= K <= F.
std::vector<int64_t> inputPositions(int frames, int views);

}  // namespace spar::cli::eval
