// model/label_maps (label logits at H/2 x W/2 and full-resolution maps on the engine, fp32)
// against the semantic fixture's float64 goldens (semantic_features.npy + text_embeddings.npy ->
// label_logits.npy, label_maps.npy, made by spar-reference goldens --labels), plus random
// odd-sized cases, ties and one-pixel structure against a float64 CPU reference of the official
// order (the logits x2 bilinear with align_corners, then the argmax); and model/label_outputs
// (labels_XX.png / .json) against the files spar-reference render --labels writes for the fixture.
#include <set>
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <system_error>

#include <unistd.h>

#include "imaging/image_prep.h"
#include "model/label_maps.h"
#include "imaging/label_outputs.h"
#include "formats/npy.h"
#include "tests/golden_support.h"
#include "tests/label_reference.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;

struct LabelResult {
  std::vector<float> logits;
  std::vector<int32_t> maps;
};

LabelResult runLabels(Engine& engine, const std::vector<float>& features, const Shape& fshape,
                      const std::vector<float>& text, const Shape& tshape) {
  const int64_t R = fshape[0], h = fshape[2], w = fshape[3], P = tshape[0];
  GuardedOutput logits(engine, {R, P, h, w});
  const Tensor maps = engine.tensor({R, 2 * h, 2 * w}, DType::I32);
  Recorder rec(engine);
  labelMaps(rec, engine.fromFloats(fshape, features), engine.fromFloats(tshape, text), maps, logits.tensor());
  rec.run();
  logits.expectAllWritten();
  LabelResult r{logits.read(), std::vector<int32_t>(size_t(maps.numel()))};
  engine.read(maps, r.maps.data(), r.maps.size() * sizeof(int32_t));
  return r;
}

// clip_text.label_logits in float64.
std::vector<double> logitsRef(const std::vector<double>& f, const Shape& fs, const std::vector<double>& t, int64_t P) {
  const int64_t R = fs[0], C = fs[1], n = fs[2] * fs[3];
  std::vector<double> tn(t.size()), out(size_t(R * P * n));
  for (int64_t p = 0; p < P; ++p) {
    double s = 0;
    for (int64_t c = 0; c < C; ++c) s += t[size_t(p * C + c)] * t[size_t(p * C + c)];
    for (int64_t c = 0; c < C; ++c) tn[size_t(p * C + c)] = t[size_t(p * C + c)] / std::sqrt(s);
  }
  for (int64_t r = 0; r < R; ++r)
    for (int64_t i = 0; i < n; ++i) {
      double s = 0;
      for (int64_t c = 0; c < C; ++c) s += f[size_t((r * C + c) * n + i)] * f[size_t((r * C + c) * n + i)];
      const double norm = std::sqrt(s);
      for (int64_t p = 0; p < P; ++p) {
        double d = 0;
        for (int64_t c = 0; c < C; ++c) d += f[size_t((r * C + c) * n + i)] / norm * tn[size_t(p * C + c)];
        out[size_t((r * P + p) * n + i)] = kLsegLogitScale * d;
      }
    }
  return out;
}

// Maps must equal the reference's except where its top two scores are closer than `tie`.
void expectMapsMatch(const std::vector<int32_t>& got, const std::vector<int64_t>& want, const std::vector<double>& logits,
                     int64_t R, int64_t P, int64_t n, double tie, const std::string& what) {
  int64_t differ = 0, nearTies = 0;
  for (int64_t r = 0; r < R; ++r)
    for (int64_t i = 0; i < n; ++i) {
      const int64_t k = r * n + i;
      if (got[size_t(k)] == want[size_t(k)]) continue;
      ++differ;
      std::vector<double> v;
      for (int64_t p = 0; p < P; ++p) v.push_back(logits[size_t((r * P + p) * n + i)]);
      std::sort(v.rbegin(), v.rend());
      if (P > 1 && v[0] - v[1] < tie) ++nearTies;
      else ADD_FAILURE() << what << ": view " << r << " pixel " << i << " label " << got[size_t(k)] << ", reference "
                         << want[size_t(k)];
    }
  std::printf("%s: %lld of %lld labels differ (%lld near-ties, top-2 gap < %g)\n", what.c_str(), (long long)differ,
              (long long)(R * n), (long long)nearTies, tie);
}

class LabelMapsTest : public EngineTest {};

TEST_F(LabelMapsTest, MatchesFixtureGoldens) {
  const GoldenCase g(semanticGoldenPath("semantic"));
  Shape fs = g.shape("semantic_features");  // [1, R, C, h, w]: the reference keeps the batch
  if (fs.size() == 5 && fs[0] == 1) fs.erase(fs.begin());
  const Shape ts = g.shape("text_embeddings");
  const int64_t R = fs[0], P = ts[0], n = fs[2] * fs[3];
  ASSERT_EQ(g.shape("label_logits"), (Shape{R, P, fs[2], fs[3]}));
  const LabelResult r = runLabels(eng(), g.floats("semantic_features"), fs, g.floats("text_embeddings"), ts);
  const std::vector<double> want = g.doubles("label_logits");
  expectClose(r.logits, want, 1e-11, 1e-4, "label logits vs float64 goldens");
  // the maps at the image's size, as the reference makes them (full_resolution_labels)
  ASSERT_EQ(g.shape("label_maps"), (Shape{R, 2 * fs[2], 2 * fs[3]}));
  expectMapsMatch(r.maps, g.array("label_maps").toInt64s(), upsampledLogits(want, R, P, fs[2], fs[3]), R, P, 4 * n, 1e-5,
                  "label maps vs goldens");
}

// Random features with a large mean and odd sizes, and prompts of which two are identical
// (exact ties: argmax takes the first, as torch does).
// Needs neither the fixture nor the BPE table: runs everywhere.
class LabelMapsOpTest : public EngineTest {};

TEST_F(LabelMapsOpTest, OddSizesAndTies) {
  const Shape fs = {3, 61, 7, 9};
  const int64_t P = 5, C = fs[1], n = fs[2] * fs[3];
  std::vector<float> f = randomNormal(size_t(shapeNumel(fs)), 3.0f, 1.0f, 401);
  std::vector<float> t = randomNormal(size_t(P * C), 0.0f, 1.0f, 402);
  std::copy_n(t.begin() + C, C, t.begin() + 3 * C);  // prompt 3 == prompt 1
  const LabelResult r = runLabels(eng(), f, fs, t, {P, C});
  const std::vector<double> want = logitsRef(toDouble(f), fs, toDouble(t), P);
  expectClose(r.logits, want, 1e-11, 1e-4, "label logits, random");
  const std::vector<double> up = upsampledLogits(want, fs[0], P, fs[2], fs[3]);
  expectMapsMatch(r.maps, firstArgmax(up, fs[0], P, 4 * n), up, fs[0], P, 4 * n, 1e-5, "label maps, random");
  for (int32_t m : r.maps) EXPECT_NE(m, 3) << "an exact tie must go to the first prompt";
}

// One-pixel structure: the labels change from one half-resolution pixel to the next, so the
// official order (scores enlarged, then the argmax) gives another map than the half-resolution
// argmax enlarged by nearest neighbour; the engine's must be the official one. Two prompts whose
// scores are a checkerboard of unequal margins: between two cells the interpolated scores
// cross where the margins say, not at the cell's edge.
TEST_F(LabelMapsOpTest, FullResolutionIsTheOfficialOrderNotTheHalfMapEnlarged) {
  const int64_t R = 2, P = 2, C = 2, h = 9, w = 11, n = h * w;
  // features [R, C, h, w] at angle theta from prompt 0 = (1, 0) toward prompt 1 = (0, 1):
  // cos(theta) and sin(theta) are the two scores before the scale
  std::vector<float> f(size_t(R * C * n)), t = {1, 0, 0, 1};
  for (int64_t r = 0; r < R; ++r)
    for (int64_t y = 0; y < h; ++y)
      for (int64_t x = 0; x < w; ++x) {
        const bool one = (x + y + r) % 2 == 1;
        // label 1 wins by a small margin, label 0 by a large one (and the margins vary)
        const double theta = one ? 0.80 + 0.01 * double((x * 7 + y * 3) % 5) : 0.15 + 0.02 * double((x + 2 * y) % 4);
        f[size_t((r * C + 0) * n + y * w + x)] = float(std::cos(theta));
        f[size_t((r * C + 1) * n + y * w + x)] = float(std::sin(theta));
      }
  const LabelResult got = runLabels(eng(), f, {R, C, h, w}, t, {P, C});
  const std::vector<double> logits = logitsRef(toDouble(f), {R, C, h, w}, toDouble(t), P);
  const std::vector<double> up = upsampledLogits(logits, R, P, h, w);
  const std::vector<int64_t> official = firstArgmax(up, R, P, 4 * n);
  expectMapsMatch(got.maps, official, up, R, P, 4 * n, 1e-5, "one-pixel structure, official order");
  // ... which is not the half-resolution argmax enlarged
  const std::vector<int64_t> half = firstArgmax(logits, R, P, n);
  int64_t other = 0;
  for (int64_t r = 0; r < R; ++r)
    for (int64_t y = 0; y < 2 * h; ++y)
      for (int64_t x = 0; x < 2 * w; ++x)
        other += official[size_t((r * 2 * h + y) * 2 * w + x)] != half[size_t((r * h + y / 2) * w + x / 2)];
  std::printf("  %lld of %lld pixels differ between the official order and the half map enlarged\n", (long long)other,
              (long long)(R * 4 * n));
  EXPECT_GT(other, R * 4 * n / 5);
}

TEST_F(LabelMapsOpTest, OnePromptAndBadShapes) {
  const Shape fs = {1, 8, 4, 4};
  const LabelResult r = runLabels(eng(), randomUniform(size_t(shapeNumel(fs)), -1, 1, 403), fs,
                                  randomUniform(8, -1, 1, 404), {1, 8});
  EXPECT_EQ(r.maps.size(), 64u);
  for (int32_t m : r.maps) EXPECT_EQ(m, 0);
  Recorder rec(eng());
  EXPECT_THROW(labelMaps(rec, eng().tensor(fs), eng().tensor({2, 7}), eng().tensor({1, 8, 8}, DType::I32)), Error);
  EXPECT_THROW(labelMaps(rec, eng().tensor(fs), eng().tensor({2, 8}), eng().tensor({1, 8, 8})), Error);
  // the maps are at twice the features' size: a half-resolution map is refused
  EXPECT_THROW(labelMaps(rec, eng().tensor(fs), eng().tensor({2, 8}), eng().tensor({1, 4, 4}, DType::I32)), Error);
}

// ---------------------------------------------------------------------------------------------
// labels_XX.png / .json against spar-reference render --labels on the fixture.

// spar-reference render --labels of the fixture's semantic case (frames 0..4, inputs 0,2,4, the
// labels of labels.json), made once per build in the spar_goldens_semantic fixture.
std::string referenceRenderDir() { return semanticGoldenPath("label_render"); }

// <dir>/labels_XX, the stem write_render uses.
std::string labelStem(const std::string& dir, int view) {
  char name[32];
  std::snprintf(name, sizeof name, "/labels_%02d", view);
  return dir + name;
}


TEST_F(LabelMapsTest, WritersMatchReferenceRender) {
  const std::string refDir = referenceRenderDir();
  std::ifstream lf(semanticGoldenPath("labels.json"));
  const std::vector<std::string> labels = nlohmann::json::parse(lf).get<std::vector<std::string>>();
  // The PNGs and the maps are at the model's H x W (the configuration's image size).
  const nlohmann::json cfg = nlohmann::json::parse(readText(semanticGoldenPath("tiny_semantic.json")));
  const int H = cfg.at("image_height").get<int>(), W = cfg.at("image_width").get<int>();
  int views = 0, h0 = 0, w0 = 0;
  std::vector<int32_t> allMaps;
  for (; fs::exists(labelStem(refDir, views) + ".png"); ++views) {
    const std::string stem = labelStem(refDir, views);
    const RgbImage png = loadImageRGB(stem + ".png");
    const nlohmann::json doc = nlohmann::json::parse(readText(stem + ".json"));
    const int h = doc.at("resolution")[0].get<int>(), w = doc.at("resolution")[1].get<int>();
    ASSERT_EQ(h, H);
    ASSERT_EQ(w, W);
    ASSERT_EQ(png.height, H + 14 * int(labels.size()) + 4);
    // The reference's map, read back from its PNG (a pixel a label).
    std::vector<int32_t> map(size_t(h * w), -1);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        const uint8_t* px = &png.pixels[(size_t(y) * png.width + size_t(x)) * 3];
        for (size_t k = 0; k < labels.size(); ++k) {
          const auto c = paletteColour(int64_t(k));
          if (px[0] == c[0] && px[1] == c[1] && px[2] == c[2]) map[size_t(y * w + x)] = int32_t(k);
        }
        ASSERT_GE(map[size_t(y * w + x)], 0) << "pixel " << x << "," << y << " has no palette colour";
      }
    // Every pixel equal except the legend's text (the reference draws it with PIL's font, we with DejaVu).
    const RgbImage mine = labelImage(map, h, w, labels, H, W);
    ASSERT_EQ(mine.width, png.width);
    ASSERT_EQ(mine.height, png.height);
    int64_t differ = 0, text = 0;
    for (int y = 0; y < png.height; ++y)
      for (int x = 0; x < png.width; ++x) {
        const size_t i = (size_t(y) * png.width + size_t(x)) * 3;
        const bool same = std::equal(&mine.pixels[i], &mine.pixels[i] + 3, &png.pixels[i]);
        if (y >= H && x >= 14) {
          text += !same;
          continue;
        }
        differ += !same;
      }
    EXPECT_EQ(differ, 0) << "view " << views;
    std::printf("labels_%02d.png: %lld pixels differ outside the legend text (%lld legend text pixels differ: other font)\n", views,
                (long long)differ, (long long)text);
    // The JSON, byte for byte.
    const std::string json = labelJsonText(labelJson(map, h, w, labels, views, kLsegLogitScale));
    EXPECT_EQ(json, readText(stem + ".json")) << "labels_" << views << ".json";
    allMaps.insert(allMaps.end(), map.begin(), map.end());
    h0 = h;
    w0 = w;
  }
  ASSERT_GT(views, 0) << "the reference wrote no labels_XX.png";
  // The file writers, all views at once: PNGs as labelImage gives them, JSON as the reference's.
  const fs::path out = fs::path(SPAR_TEST_OUT_DIR) / ("label_writer_" + std::to_string(::getpid()));
  fs::create_directories(out);
  writeLabelFiles(out.string(), allMaps, views, h0, w0, labels, H, W);
  for (int v = 0; v < views; ++v) {
    const std::vector<int32_t> map(allMaps.begin() + v * h0 * w0, allMaps.begin() + (v + 1) * h0 * w0);
    EXPECT_EQ(loadImageRGB(labelStem(out.string(), v) + ".png").pixels, labelImage(map, h0, w0, labels, H, W).pixels);
    EXPECT_EQ(readText(labelStem(out.string(), v) + ".json"), readText(labelStem(refDir, v) + ".json"));
  }
  fs::remove_all(out);
}

// The legend's names: drawn right of the swatches when the font is installed (scripts/
// install-deps.sh installs it), only in the legend's text area; the map and swatches untouched.
TEST(LabelOutputs, LegendNamesAreDrawnBesideSwatches) {
  if (legendFont().empty()) GTEST_SKIP() << "DejaVu Sans not installed (fonts-dejavu-core)";
  const int h = 4, w = 6, H = 32, W = 48;
  const std::vector<int32_t> map(size_t(h * w), 1);
  const std::vector<std::string> names = {"sofa", "window", "ünïcödé chäir"};
  const RgbImage with = labelImage(map, h, w, names, H, W);
  RgbImage without = with;
  // the same image with the names' text area cleared must equal a drawing without names
  int64_t textPixels = 0, elsewhere = 0;
  for (int y = 0; y < with.height; ++y)
    for (int x = 0; x < with.width; ++x) {
      const uint8_t* p = &with.pixels[(size_t(y) * with.width + size_t(x)) * 3];
      const bool lit = p[0] || p[1] || p[2];
      if (y >= H && x >= 14) textPixels += lit;
      else if (y >= H && x > 12) elsewhere += lit;
    }
  EXPECT_GT(textPixels, 30) << "no name drawn";
  EXPECT_EQ(elsewhere, 0);
  // every legend row got some text
  for (size_t k = 0; k < names.size(); ++k) {
    int64_t row = 0;
    for (int y = H + 2 + 14 * int(k); y < H + 2 + 14 * int(k + 1); ++y)
      for (int x = 14; x < with.width; ++x) row += with.pixels[(size_t(y) * with.width + size_t(x)) * 3] != 0;
    EXPECT_GT(row, 5) << names[k];
  }
  // the map part is the palette colour of label 1
  const auto c = paletteColour(1);
  EXPECT_TRUE(std::equal(c.begin(), c.end(), with.pixels.begin()));
}

TEST(LabelOutputs, PaletteAndChecks) {
  EXPECT_EQ(paletteColour(0), (std::array<uint8_t, 3>{230, 25, 75}));
  EXPECT_EQ(paletteColour(19), (std::array<uint8_t, 3>{128, 128, 128}));
  // More labels than the palette: each its own colour, none black (the legend's background).
  std::set<std::array<uint8_t, 3>> seen;
  for (int64_t k = 0; k < 5000; ++k) {
    const auto c = paletteColour(k);
    EXPECT_TRUE(seen.insert(c).second) << "label " << k << " repeats a colour";
    EXPECT_NE(c, (std::array<uint8_t, 3>{0, 0, 0})) << k;
  }
  EXPECT_THROW(labelImage({0, 2}, 1, 2, {"a", "b"}, 2, 4), Error);  // label 2 of 2
  EXPECT_THROW(labelJson({0}, 1, 2, {"a"}, 0, 1.0), Error);       // 1 value for 1 x 2
}

}  // namespace
}  // namespace spar::test
