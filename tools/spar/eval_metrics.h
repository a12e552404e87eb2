// The metrics of `spar eval` (evaluation/PROTOCOL.md, "Metrics"), as pure functions on
// host arrays: no Vulkan, no files, so tests check them against hand computations. Everything
// accumulates in double. Layouts: images [3, H, W] (CHW, values in [0, 1]); masks and class maps
// [H, W] row-major; a "dynamic" mask holds 0 (static) or 1 (dynamic, ground truth).
#pragma once
#include <cstdint>
#include <optional>
#include <vector>

namespace spar::cli::eval {

// PSNR over the static pixels of one view: mse = sum over static p and RGB of (render - gt)^2 /
// (3 |S|), PSNR = 10 log10(1 / mse). nullopt when no pixel is static (the view is skipped);
// +inf when the static pixels are identical.
std::optional<double> staticPsnr(const float* render, const float* gt, const uint8_t* dynamic, int height, int width);

// SSIM over the static pixels of one view: per channel, 11x11 Gaussian window (sigma 1.5,
// weights summing to 1), C1 = 0.01^2, C2 = 0.03^2, map only at centres where the window fits
// (5 <= y <= H-6, 5 <= x <= W-6); mean over the channels and the valid centres whose centre
// pixel is static. nullopt when there is no such centre.
std::optional<double> staticSsim(const float* render, const float* gt, const uint8_t* dynamic, int height, int width);

// The 11 normalized weights of the 1-D Gaussian (the 2-D window is their outer product).
std::vector<double> ssimGaussian1d();

// Motion-mask confusion counts: predicted dynamic = P(dynamic) > threshold.
struct MaskCounts {
  int64_t tp = 0, fp = 0, fn = 0, tn = 0;
  void add(const float* probability, const uint8_t* dynamic, size_t pixels, float threshold = 0.5f);
  void add(const MaskCounts& other);  // pooling: scenes, shards
  // nullopt where the denominator is 0 (nothing to measure).
  std::optional<double> iouDynamic() const;
  std::optional<double> iouStatic() const;
  std::optional<double> meanIou() const;  // (IoU_dyn + IoU_static) / 2
  std::optional<double> recall() const;   // TP / (TP + FN)
};

// Semantic confusion matrix over label maps at the image's size (PROTOCOL.md, "Semantics"): a
// pixel is evaluated iff it is static; its ground truth is its class id.
class SemanticConfusion {
 public:
  explicit SemanticConfusion(int classes);
  // labels, classes, dynamic: [H, W] (predicted ids, true ids, 1 = dynamic). A ground-truth id outside
  // [0, classes) throws spar::Error (the scene's class maps and classes.json disagree); a
  // predicted id outside counts as wrong for every class.
  void add(const int32_t* labels, const int32_t* classes, const uint8_t* dynamic, int height, int width);
  // Pooling (scenes, shards): the counts of `other`, which must have as many classes.
  void add(const SemanticConfusion& other);
  // The counts as they are, and back (a result file's per-scene tallies); fromCounts throws
  // spar::Error when the sizes do not fit `classes` or a count is negative.
  static SemanticConfusion fromCounts(int classes, std::vector<int64_t> matrix, std::vector<int64_t> unknown,
                                      int64_t evaluated, int64_t correct);
  int classes() const { return classes_; }
  const std::vector<int64_t>& matrix() const { return matrix_; }
  const std::vector<int64_t>& unknown() const { return unknown_; }
  int64_t correct() const { return correct_; }
  int64_t evaluated() const { return evaluated_; }
  int64_t count(int truth, int predicted) const { return matrix_[size_t(truth) * classes_ + predicted]; }
  std::optional<double> accuracy() const;  // correct / evaluated
  // Mean over the classes with at least one ground-truth pixel of TP / (TP + FP + FN).
  std::optional<double> meanIou() const;

 private:
  int classes_;
  std::vector<int64_t> matrix_;   // [truth][predicted]
  std::vector<int64_t> unknown_;  // [truth]: predicted ids outside the classes (misses)
  int64_t evaluated_ = 0, correct_ = 0;
};

// The baselines a model must beat (PROTOCOL.md, "Baselines"), scored like its renderings.
// The input nearest to target frame t in sequence position (ties: the earlier one).
int64_t nearestInput(int64_t target, const std::vector<int64_t>& inputs);
// [3, H, W]: every pixel the mean colour of the input views (all their pixels). rgb: [F, 3, H, W].
std::vector<float> meanColourImage(const std::vector<float>& rgb, const std::vector<int64_t>& inputs, int height,
                                   int width);

// Median of the values (mean of the two middle ones for an even count); nullopt when empty.
std::optional<double> median(std::vector<double> values);

}  // namespace spar::cli::eval
