#include "tools/spar/eval_metrics.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "spar/error.h"

namespace spar::cli::eval {
namespace {

constexpr int kRadius = 5;  // 11x11 window
constexpr double kSigma = 1.5, kC1 = 0.01 * 0.01, kC2 = 0.03 * 0.03;

}  // namespace

int64_t nearestInput(int64_t target, const std::vector<int64_t>& inputs) {
  if (inputs.empty()) throw Error("nearestInput: no inputs");
  int64_t best = inputs.front();
  for (int64_t i : inputs)
    if (std::abs(i - target) < std::abs(best - target) || (std::abs(i - target) == std::abs(best - target) && i < best))
      best = i;
  return best;
}

std::vector<float> meanColourImage(const std::vector<float>& rgb, const std::vector<int64_t>& inputs, int height,
                                   int width) {
  const size_t plane = size_t(height) * size_t(width);
  std::vector<float> out(3 * plane);
  for (int c = 0; c < 3; ++c) {
    double sum = 0;
    for (int64_t i : inputs)
      for (size_t p = 0; p < plane; ++p) sum += rgb[(size_t(i) * 3 + c) * plane + p];
    const float mean = float(sum / double(inputs.size() * plane));
    std::fill(out.begin() + c * plane, out.begin() + (c + 1) * plane, mean);
  }
  return out;
}

std::optional<double> staticPsnr(const float* render, const float* gt, const uint8_t* dynamic, int height, int width) {
  const size_t plane = size_t(height) * size_t(width);
  double sum = 0;
  int64_t n = 0;
  for (size_t p = 0; p < plane; ++p) {
    if (dynamic[p]) continue;
    ++n;
    for (int c = 0; c < 3; ++c) {
      const double d = double(render[c * plane + p]) - double(gt[c * plane + p]);
      sum += d * d;
    }
  }
  if (n == 0) return std::nullopt;
  const double mse = sum / (3.0 * double(n));
  if (mse == 0) return std::numeric_limits<double>::infinity();
  return 10.0 * std::log10(1.0 / mse);
}

std::vector<double> ssimGaussian1d() {
  std::vector<double> g(2 * kRadius + 1);
  double total = 0;
  for (int i = -kRadius; i <= kRadius; ++i) total += g[i + kRadius] = std::exp(-double(i * i) / (2 * kSigma * kSigma));
  for (double& v : g) v /= total;
  return g;
}

std::optional<double> staticSsim(const float* render, const float* gt, const uint8_t* dynamic, int height, int width) {
  if (height < 2 * kRadius + 1 || width < 2 * kRadius + 1) return std::nullopt;
  const std::vector<double> g = ssimGaussian1d();
  const size_t plane = size_t(height) * size_t(width);
  // The window is separable: filter the five moments along x over all rows (only at x where
  // it fits), then along y at the centres that count.
  const int cw = width - 2 * kRadius;  // valid centre columns x = kRadius .. W-1-kRadius
  std::vector<double> rows(size_t(5) * height * cw);
  double sum = 0;
  int64_t centres = 0;
  for (int c = 0; c < 3; ++c) {
    const float* a = render + c * plane;
    const float* b = gt + c * plane;
    for (int y = 0; y < height; ++y)
      for (int x = 0; x < cw; ++x) {
        double m[5] = {0, 0, 0, 0, 0};
        for (int i = 0; i < 2 * kRadius + 1; ++i) {
          const size_t p = size_t(y) * width + x + i;
          const double u = a[p], v = b[p], wt = g[i];
          m[0] += wt * u, m[1] += wt * v, m[2] += wt * u * u, m[3] += wt * v * v, m[4] += wt * u * v;
        }
        for (int k = 0; k < 5; ++k) rows[(size_t(k) * height + y) * cw + x] = m[k];
      }
    for (int y = kRadius; y < height - kRadius; ++y)
      for (int x = 0; x < cw; ++x) {
        if (dynamic[size_t(y) * width + x + kRadius]) continue;
        double m[5] = {0, 0, 0, 0, 0};
        for (int i = 0; i < 2 * kRadius + 1; ++i)
          for (int k = 0; k < 5; ++k) m[k] += g[i] * rows[(size_t(k) * height + y - kRadius + i) * cw + x];
        const double mx = m[0], my = m[1];
        const double vx = m[2] - mx * mx, vy = m[3] - my * my, cov = m[4] - mx * my;
        sum += ((2 * mx * my + kC1) * (2 * cov + kC2)) / ((mx * mx + my * my + kC1) * (vx + vy + kC2));
        if (c == 0) ++centres;
      }
  }
  if (centres == 0) return std::nullopt;
  return sum / (3.0 * double(centres));
}

void MaskCounts::add(const float* probability, const uint8_t* dynamic, size_t pixels, float threshold) {
  for (size_t p = 0; p < pixels; ++p) {
    const bool predicted = probability[p] > threshold, truth = dynamic[p] != 0;
    if (predicted && truth) ++tp;
    else if (predicted) ++fp;
    else if (truth) ++fn;
    else ++tn;
  }
}

void MaskCounts::add(const MaskCounts& o) {
  tp += o.tp, fp += o.fp, fn += o.fn, tn += o.tn;
}

namespace {
std::optional<double> ratio(int64_t num, int64_t den) {
  if (den == 0) return std::nullopt;
  return double(num) / double(den);
}
}  // namespace

std::optional<double> MaskCounts::iouDynamic() const { return ratio(tp, tp + fp + fn); }
std::optional<double> MaskCounts::iouStatic() const { return ratio(tn, tn + fp + fn); }
std::optional<double> MaskCounts::recall() const { return ratio(tp, tp + fn); }
std::optional<double> MaskCounts::meanIou() const {
  const auto d = iouDynamic(), s = iouStatic();
  if (!d || !s) return std::nullopt;
  return (*d + *s) / 2;
}

SemanticConfusion::SemanticConfusion(int classes)
    : classes_(classes), matrix_(size_t(classes) * classes, 0), unknown_(size_t(classes), 0) {}

void SemanticConfusion::add(const int32_t* labels, const int32_t* classes, const uint8_t* dynamic, int height,
                            int width) {
  const size_t pixels = size_t(height) * size_t(width);
  for (size_t p = 0; p < pixels; ++p) {
    if (dynamic[p]) continue;
    const int32_t c = classes[p];
    if (c < 0 || c >= classes_)
      throw Error("class id " + std::to_string(c) + " is outside the " + std::to_string(classes_) + " classes");
    const int32_t pred = labels[p];
    ++evaluated_;
    if (pred == c) ++correct_;
    // A predicted id outside the classes has no column: it is a miss (FN of c) only.
    if (pred >= 0 && pred < classes_) ++matrix_[size_t(c) * classes_ + pred];
    else ++unknown_[size_t(c)];
  }
}

void SemanticConfusion::add(const SemanticConfusion& o) {
  if (o.classes_ != classes_)
    throw Error("semantic counts of " + std::to_string(o.classes_) + " classes added to " + std::to_string(classes_));
  for (size_t i = 0; i < matrix_.size(); ++i) matrix_[i] += o.matrix_[i];
  for (size_t i = 0; i < unknown_.size(); ++i) unknown_[i] += o.unknown_[i];
  evaluated_ += o.evaluated_, correct_ += o.correct_;
}

SemanticConfusion SemanticConfusion::fromCounts(int classes, std::vector<int64_t> matrix, std::vector<int64_t> unknown,
                                                int64_t evaluated, int64_t correct) {
  if (classes < 1 || matrix.size() != size_t(classes) * size_t(classes) || unknown.size() != size_t(classes))
    throw Error("semantic counts do not fit " + std::to_string(classes) + " classes");
  SemanticConfusion s(classes);
  for (int64_t v : matrix)
    if (v < 0) throw Error("a negative semantic count");
  for (int64_t v : unknown)
    if (v < 0) throw Error("a negative semantic count");
  if (evaluated < 0 || correct < 0 || correct > evaluated) throw Error("semantic counts: correct > evaluated");
  s.matrix_ = std::move(matrix), s.unknown_ = std::move(unknown), s.evaluated_ = evaluated, s.correct_ = correct;
  return s;
}

std::optional<double> SemanticConfusion::accuracy() const { return ratio(correct_, evaluated_); }

std::optional<double> SemanticConfusion::meanIou() const {
  double sum = 0;
  int present = 0;
  for (int c = 0; c < classes_; ++c) {
    int64_t truthTotal = 0, predTotal = 0;
    for (int k = 0; k < classes_; ++k) {
      truthTotal += matrix_[size_t(c) * classes_ + k];
      predTotal += matrix_[size_t(k) * classes_ + c];
    }
    truthTotal += unknown_[size_t(c)];
    if (truthTotal == 0) continue;
    const int64_t tp = matrix_[size_t(c) * classes_ + c];
    const int64_t fp = predTotal - tp, fn = truthTotal - tp;
    sum += double(tp) / double(tp + fp + fn);
    ++present;
  }
  if (present == 0) return std::nullopt;
  return sum / present;
}

std::optional<double> median(std::vector<double> values) {
  if (values.empty()) return std::nullopt;
  std::sort(values.begin(), values.end());
  const size_t n = values.size();
  return n % 2 ? values[n / 2] : (values[n / 2 - 1] + values[n / 2]) / 2;
}

}  // namespace spar::cli::eval
