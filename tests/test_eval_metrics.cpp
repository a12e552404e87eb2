// The metrics of `spar eval` (tools/spar/eval_metrics.*, evaluation/PROTOCOL.md)
// against independent hand computations: PSNR of a known constant error, SSIM of constant
// images in closed form, SSIM = 1 for identical images, a float64 brute-force SSIM (2-D window,
// no separability) on a small random case, motion-mask counts and semantic confusion on tiny
// hand-made maps (2x2 block rule, mixed and dynamic blocks excluded), skipped views, and the
// protocol's input positions; the per-scene tallies result.json keeps for merges and reruns
// (their JSON exact, infinities included; pooling = the counts' sums). Pure host code: no device.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "spar/error.h"
#include "tools/spar/eval_metrics.h"
#include "tools/spar/eval_scenes.h"
#include "tools/spar/eval_tally.h"

namespace spar::cli::eval {
namespace {

std::vector<float> constant(int h, int w, float v) { return std::vector<float>(size_t(3) * h * w, v); }

TEST(eval_metrics, PsnrOfAConstantErrorOnStaticPixels) {
  const int h = 6, w = 5;
  std::vector<float> gt = constant(h, w, 0.25f), render = constant(h, w, 0.375f);  // error 1/8, exact in float
  std::vector<uint8_t> dyn(size_t(h) * w, 0);
  // Dynamic pixels with a large error must not count.
  for (int p : {0, 7, 29}) {
    dyn[size_t(p)] = 1;
    for (int c = 0; c < 3; ++c) render[size_t(c) * h * w + p] = 1.0f;
  }
  const auto psnr = staticPsnr(render.data(), gt.data(), dyn.data(), h, w);
  ASSERT_TRUE(psnr.has_value());
  EXPECT_NEAR(*psnr, 10 * std::log10(64.0), 1e-12);  // mse = 1/64
}

TEST(eval_metrics, PsnrAndSsimSkipViewsWithoutStaticPixels) {
  const int h = 16, w = 16;
  const std::vector<float> a = constant(h, w, 0.2f), b = constant(h, w, 0.3f);
  const std::vector<uint8_t> allDynamic(size_t(h) * w, 1);
  EXPECT_FALSE(staticPsnr(a.data(), b.data(), allDynamic.data(), h, w).has_value());
  EXPECT_FALSE(staticSsim(a.data(), b.data(), allDynamic.data(), h, w).has_value());
  // Only the border (where no SSIM centre lies) static: PSNR is measured, SSIM skipped.
  std::vector<uint8_t> borderStatic(size_t(h) * w, 0);
  for (int y = 5; y <= h - 6; ++y)
    for (int x = 5; x <= w - 6; ++x) borderStatic[size_t(y) * w + x] = 1;
  EXPECT_TRUE(staticPsnr(a.data(), b.data(), borderStatic.data(), h, w).has_value());
  EXPECT_FALSE(staticSsim(a.data(), b.data(), borderStatic.data(), h, w).has_value());
  // A window that does not fit at all: no centre.
  const std::vector<uint8_t> none(size_t(10) * 10, 0);
  EXPECT_FALSE(staticSsim(a.data(), b.data(), none.data(), 10, 10).has_value());
}

TEST(eval_metrics, SsimOfIdenticalImagesIsOne) {
  const int h = 20, w = 23;
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  std::vector<float> img(size_t(3) * h * w);
  for (float& v : img) v = u(rng);
  std::vector<uint8_t> dyn(size_t(h) * w, 0);
  for (size_t p = 0; p < dyn.size(); p += 7) dyn[p] = 1;
  const auto s = staticSsim(img.data(), img.data(), dyn.data(), h, w);
  ASSERT_TRUE(s.has_value());
  EXPECT_NEAR(*s, 1.0, 1e-12);
}

TEST(eval_metrics, SsimOfConstantImagesInClosedForm) {
  // Constant images: no variance, no covariance: SSIM = (2ab + C1) / (a^2 + b^2 + C1) everywhere.
  const int h = 12, w = 14;
  const double a = 0.5, b = 0.25, c1 = 1e-4;
  const std::vector<float> x = constant(h, w, float(a)), y = constant(h, w, float(b));
  const std::vector<uint8_t> dyn(size_t(h) * w, 0);
  const auto s = staticSsim(x.data(), y.data(), dyn.data(), h, w);
  ASSERT_TRUE(s.has_value());
  EXPECT_NEAR(*s, (2 * a * b + c1) / (a * a + b * b + c1), 1e-12);
}

// Brute force in float64 as the protocol words it: the 2-D 11x11 Gaussian normalized to sum 1,
// moments summed over the window at each valid centre, mean over channels and static centres.
double bruteForceSsim(const std::vector<float>& x, const std::vector<float>& y, const std::vector<uint8_t>& dyn,
                      int h, int w) {
  double win[11][11], total = 0;
  for (int i = 0; i < 11; ++i)
    for (int j = 0; j < 11; ++j) total += win[i][j] = std::exp(-((i - 5) * (i - 5) + (j - 5) * (j - 5)) / (2 * 1.5 * 1.5));
  for (auto& row : win)
    for (double& v : row) v /= total;
  const double c1 = 0.01 * 0.01, c2 = 0.03 * 0.03;
  double sum = 0;
  int count = 0;
  for (int c = 0; c < 3; ++c)
    for (int cy = 5; cy <= h - 6; ++cy)
      for (int cx = 5; cx <= w - 6; ++cx) {
        if (dyn[size_t(cy) * w + cx]) continue;
        double mx = 0, my = 0, xx = 0, yy = 0, xy = 0;
        for (int i = 0; i < 11; ++i)
          for (int j = 0; j < 11; ++j) {
            const size_t p = size_t(c) * h * w + size_t(cy - 5 + i) * w + (cx - 5 + j);
            const double a = x[p], b = y[p], g = win[i][j];
            mx += g * a, my += g * b, xx += g * a * a, yy += g * b * b, xy += g * a * b;
          }
        const double vx = xx - mx * mx, vy = yy - my * my, cov = xy - mx * my;
        sum += (2 * mx * my + c1) * (2 * cov + c2) / ((mx * mx + my * my + c1) * (vx + vy + c2));
        ++count;
      }
  return sum / count;
}

TEST(eval_metrics, SsimMatchesABruteForceReference) {
  const int h = 16, w = 16;
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0.f, 1.f), noise(-0.2f, 0.2f);
  std::vector<float> gt(size_t(3) * h * w), render(gt.size());
  for (size_t i = 0; i < gt.size(); ++i) {
    gt[i] = u(rng);
    render[i] = std::fmin(1.f, std::fmax(0.f, gt[i] + noise(rng)));
  }
  std::vector<uint8_t> dyn(size_t(h) * w, 0);
  std::bernoulli_distribution coin(0.3);
  for (auto& d : dyn) d = coin(rng) ? 1 : 0;
  const auto s = staticSsim(render.data(), gt.data(), dyn.data(), h, w);
  ASSERT_TRUE(s.has_value());
  const double expected = bruteForceSsim(render, gt, dyn, h, w);
  std::printf("  SSIM %.12f, brute force %.12f\n", *s, expected);
  EXPECT_NEAR(*s, expected, 1e-12);
  EXPECT_GT(*s, 0.0);
  EXPECT_LT(*s, 1.0);
}

TEST(eval_metrics, MaskCountsOnAHandMadeCase) {
  // P(dynamic) > 0.5 is dynamic (0.5 itself is not).
  const std::vector<float> prob = {0.9f, 0.6f, 0.4f, 0.1f, 0.5f, 0.51f, 0.0f};
  const std::vector<uint8_t> truth = {1, 0, 1, 0, 0, 1, 0};
  MaskCounts m;
  m.add(prob.data(), truth.data(), prob.size());
  EXPECT_EQ(m.tp, 2);  // 0.9, 0.51
  EXPECT_EQ(m.fp, 1);  // 0.6
  EXPECT_EQ(m.fn, 1);  // 0.4
  EXPECT_EQ(m.tn, 3);  // 0.1, 0.5, 0.0
  EXPECT_DOUBLE_EQ(*m.iouDynamic(), 2.0 / 4);
  EXPECT_DOUBLE_EQ(*m.iouStatic(), 3.0 / 5);
  EXPECT_DOUBLE_EQ(*m.meanIou(), (0.5 + 0.6) / 2);
  EXPECT_DOUBLE_EQ(*m.recall(), 2.0 / 3);
  // Counts accumulate over frames.
  m.add(prob.data(), truth.data(), prob.size());
  EXPECT_EQ(m.tp + m.fp + m.fn + m.tn, 14);
  EXPECT_DOUBLE_EQ(*m.iouDynamic(), 4.0 / 8);

  // Nothing dynamic anywhere: IoU_dyn and recall undefined, IoU_static 1.
  MaskCounts still;
  const std::vector<float> low(4, 0.1f);
  const std::vector<uint8_t> zero(4, 0);
  still.add(low.data(), zero.data(), 4);
  EXPECT_FALSE(still.iouDynamic().has_value());
  EXPECT_FALSE(still.recall().has_value());
  EXPECT_FALSE(still.meanIou().has_value());
  EXPECT_DOUBLE_EQ(*still.iouStatic(), 1.0);
}

// PROTOCOL.md "Semantics": label maps at the image's size, every static pixel evaluated.
TEST(eval_metrics, SemanticConfusionOverStaticPixels) {
  // Two 2x3 views, 4 classes; class 3 is predicted but never ground truth.
  const int h = 2, w = 3;
  // View 1: pixel (1,1) is dynamic (not evaluated, whatever its label).
  const std::vector<int32_t> cls1 = {1, 1, 2,  //
                                     2, 2, 0};
  std::vector<uint8_t> dyn1(6, 0);
  dyn1[size_t(1) * w + 1] = 1;
  const std::vector<int32_t> lab1 = {1, 3, 2,  //
                                     0, 9, 0};
  // View 2: all static.
  const std::vector<int32_t> cls2 = {0, 0, 1,  //
                                     1, 2, 2};
  const std::vector<uint8_t> dyn2(6, 0);
  const std::vector<int32_t> lab2 = {0, 2, 1,  //
                                     3, 2, 0};

  SemanticConfusion s(4);
  s.add(lab1.data(), cls1.data(), dyn1.data(), h, w);
  EXPECT_EQ(s.evaluated(), 5);
  s.add(lab2.data(), cls2.data(), dyn2.data(), h, w);
  EXPECT_EQ(s.evaluated(), 11);
  // truth -> predicted: view 1: 1->1, 1->3, 2->2, 2->0, 0->0; view 2: 0->0, 0->2, 1->1, 1->3, 2->2, 2->0
  EXPECT_EQ(s.count(1, 1), 2);
  EXPECT_EQ(s.count(1, 3), 2);
  EXPECT_EQ(s.count(2, 2), 2);
  EXPECT_EQ(s.count(2, 0), 2);
  EXPECT_EQ(s.count(0, 0), 2);
  EXPECT_EQ(s.count(0, 2), 1);
  EXPECT_DOUBLE_EQ(*s.accuracy(), 6.0 / 11);
  // IoU: class 0: TP 2, FP 2 (2->0), FN 1 (0->2) = 2/5; class 1: TP 2, FN 2 (1->3) = 2/4;
  // class 2: TP 2, FP 1 (0->2), FN 2 (2->0) = 2/5; class 3: no ground truth, left out.
  EXPECT_NEAR(*s.meanIou(), (2.0 / 5 + 2.0 / 4 + 2.0 / 5) / 3, 1e-15);

  // Nothing evaluated: undefined.
  SemanticConfusion empty(4);
  const std::vector<uint8_t> allDyn(6, 1);
  empty.add(lab2.data(), cls2.data(), allDyn.data(), h, w);
  EXPECT_EQ(empty.evaluated(), 0);
  EXPECT_FALSE(empty.accuracy().has_value());
  EXPECT_FALSE(empty.meanIou().has_value());
  // A ground-truth id outside the classes is an error, a predicted one a miss.
  const std::vector<int32_t> badTruth = {0, 0, 7, 0, 0, 0};
  EXPECT_THROW(empty.add(lab2.data(), badTruth.data(), dyn2.data(), h, w), std::exception);
}

TEST(eval_metrics, InputPositionsFollowTheProtocol) {
  using V = std::vector<int64_t>;
  EXPECT_EQ(inputPositions(8, 2), (V{0, 7}));
  EXPECT_EQ(inputPositions(8, 3), (V{0, 4, 7}));
  EXPECT_EQ(inputPositions(8, 4), (V{0, 2, 5, 7}));
  EXPECT_EQ(inputPositions(6, 3), (V{0, 3, 5}));  // 2.5 + 0.5 = 3 exactly
  EXPECT_EQ(inputPositions(5, 5), (V{0, 1, 2, 3, 4}));
  EXPECT_THROW(inputPositions(8, 1), std::exception);
  EXPECT_THROW(inputPositions(8, 9), std::exception);
}

// PROTOCOL.md "Baselines": the nearest input in sequence position, ties to the earlier one.
TEST(eval_metrics, NearestInputTiesGoToTheEarlier) {
  EXPECT_EQ(nearestInput(1, {0, 2}), 0);
  EXPECT_EQ(nearestInput(3, {0, 2, 7}), 2);
  EXPECT_EQ(nearestInput(5, {0, 2, 7}), 7);
  EXPECT_EQ(nearestInput(6, {7, 0}), 7);
  EXPECT_THROW(nearestInput(1, {}), std::exception);
}

// The inputs' mean colour, per channel over all their pixels; other frames do not count.
TEST(eval_metrics, MeanColourOfTheInputs) {
  const int h = 3, w = 5;
  const size_t plane = size_t(h) * w;
  std::vector<float> rgb(4 * 3 * plane);
  for (size_t f = 0; f < 4; ++f)
    for (size_t c = 0; c < 3; ++c)
      for (size_t p = 0; p < plane; ++p) rgb[(f * 3 + c) * plane + p] = float(f * 0.25 + c * 0.01 + (p % 2) * 0.002);
  const std::vector<float> mean = meanColourImage(rgb, {1, 3}, h, w);
  ASSERT_EQ(mean.size(), 3 * plane);
  const double odd = double(plane / 2) / double(plane);  // share of pixels with the 0.002 offset
  for (size_t c = 0; c < 3; ++c)
    for (size_t p = 0; p < plane; ++p)
      EXPECT_NEAR(mean[c * plane + p], 0.5 + c * 0.01 + 0.002 * odd, 1e-6) << c << " " << p;
}

TEST(eval_metrics, MedianOfEvenAndOddCounts) {
  EXPECT_FALSE(median({}).has_value());
  EXPECT_DOUBLE_EQ(*median({3, 1, 2}), 2);
  EXPECT_DOUBLE_EQ(*median({4, 1, 3, 2}), 2.5);
}

SceneTally tally(double psnrSum, int64_t views, int64_t tp, int64_t truth0predicted1) {
  SceneTally t;
  t.targetViews = views + 1, t.psnrViews = views, t.ssimViews = views;
  t.psnrSum = psnrSum, t.ssimSum = 0.1 * double(views), t.copyPsnrSum = 0.3, t.copySsimSum = 1.0 / 3.0, t.meanPsnrSum = 7;
  t.masks = {tp, 1, 2, 100};
  t.refinedMasks = {0, 0, 0, 5};
  std::vector<int64_t> m = {10, truth0predicted1, 0, 20};  // 2 classes, [truth][predicted]
  t.semantic = SemanticConfusion::fromCounts(2, m, {1, 0}, 10 + truth0predicted1 + 20 + 1, 30);
  t.modelMs = 12.5, t.seconds = 0.02;
  return t;
}

// A tally survives result.json bit for bit: doubles at full precision, +inf (a view whose
// static pixels match exactly) as a string; a tally of another class count is refused.
TEST(eval_metrics, TallyJsonIsExact) {
  const SceneTally t = tally(std::numeric_limits<double>::infinity(), 3, 4, 5);
  SceneTally u = tally(0.1 + 0.2, 3, 4, 5);
  for (const SceneTally& x : {t, u}) {
    const nlohmann::json j = nlohmann::json::parse(toJson(x).dump());
    const SceneTally y = tallyFromJson(j, 2, "t");
    EXPECT_EQ(std::memcmp(&y.psnrSum, &x.psnrSum, sizeof(double)), 0);
    EXPECT_EQ(y.copySsimSum, x.copySsimSum);
    EXPECT_EQ(y.masks.tp, x.masks.tp);
    EXPECT_EQ(y.semantic->matrix(), x.semantic->matrix());
    EXPECT_EQ(y.semantic->unknown(), x.semantic->unknown());
    EXPECT_EQ(*y.semantic->meanIou(), *x.semantic->meanIou());
  }
  EXPECT_EQ(toJson(t)["psnr_sum"], "inf");
  const nlohmann::json j = nlohmann::json::parse(toJson(u).dump());
  EXPECT_THROW(tallyFromJson(j, 3, "t"), Error);
  nlohmann::json bad = j;
  bad["masks"]["tp"] = -1;
  EXPECT_THROW(tallyFromJson(bad, 2, "t"), Error);
  bad = j;
  bad.erase("psnr_sum");
  EXPECT_THROW(tallyFromJson(bad, 2, "t"), Error);
}

// The set's numbers come from the pooled sums and counts: PSNR is the sum over all views over
// their number (not the mean of the scenes' means), IoUs from the summed confusion counts.
TEST(eval_metrics, PoolingSumsCountsNotMeans) {
  const SceneTally a = tally(30.0, 1, 4, 0), b = tally(60.0, 3, 8, 6);
  const KTotals k = pool({&a, &b}, 2);
  EXPECT_DOUBLE_EQ(*k.psnr(), 90.0 / 4.0);  // the scenes' means, 30 and 20, would average 25
  EXPECT_EQ(k.sum.targetViews, 6);
  EXPECT_EQ(k.sum.masks.tp, 12);
  EXPECT_DOUBLE_EQ(*k.sum.masks.iouDynamic(), 12.0 / (12.0 + 2.0 + 4.0));
  // class 0: TP 20, FN 6 + 2 unknown; class 1: TP 40, FP 6
  EXPECT_DOUBLE_EQ(*k.sum.semantic->meanIou(), (20.0 / 28.0 + 40.0 / 46.0) / 2);
  EXPECT_EQ(k.sceneMs.size(), 2u);
  EXPECT_THROW(SemanticConfusion::fromCounts(2, {1, 2, 3}, {0, 0}, 6, 1), Error);
  EXPECT_THROW(SemanticConfusion::fromCounts(2, {1, 2, 3, 4}, {0, 0}, 10, 11), Error);
}

}  // namespace
}  // namespace spar::cli::eval
