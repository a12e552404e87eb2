// model/image_prep against PIL: tests/python/make_image_golden.py writes test images (odd sizes,
// grey, RGBA, JPEG, constant black and white, non-images) and the reference's prepared inputs
// (reference/spar_reference/images.py load_image: PIL convert("RGB"), Lanczos resize, centre
// crop, /255); the C++ loader and preparation must give the same 8-bit values.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "spar/error.h"
#include "imaging/image_prep.h"
#include "formats/npy.h"
#include "tests/golden_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;

// tests/python/make_image_golden.py's images and goldens (fixture op_goldens, made once per build).
std::string goldenDir() { return opGoldenPath("image"); }

struct GoldenCase {
  std::string name, image;
  int h = 0, w = 0;
};

std::vector<GoldenCase> readCases() {
  std::ifstream in(goldenDir() + "/cases.txt");
  std::vector<GoldenCase> cases;
  for (std::string line; std::getline(in, line);) {
    if (line.empty()) continue;
    std::istringstream ss(line);
    GoldenCase c;
    ss >> c.name >> c.image >> c.h >> c.w;
    cases.push_back(c);
  }
  return cases;
}

// max |a - b| in 8-bit steps (values are k / 255).
double maxDiff255(const std::vector<float>& a, const std::vector<float>& b) {
  double m = 0;
  for (size_t i = 0; i < a.size(); ++i) m = std::max(m, std::abs(double(a[i]) - double(b[i])) * 255.0);
  return m;
}

bool oneLine(const std::string& s) { return s.find('\n') == std::string::npos && !s.empty(); }

// The prepared inputs equal PIL's bit for bit: measured max difference 0 (in 8-bit steps) in
// every case (downscale, upscale, horizontal-only and vertical-only passes, crop only, no resize,
// grey, RGBA, JPEG), so the assertion is exact equality of the float values.
TEST(ImagePrep, PreparedMatchesPil) {
  const auto cases = readCases();
  ASSERT_GE(cases.size(), 15u);
  double worst = 0;
  for (const auto& c : cases) {
    SCOPED_TRACE(c.name);
    const NpyArray g = readNpy(goldenDir() + "/" + c.name + ".prepared.npy", {3, c.h, c.w});
    ASSERT_EQ(g.type, NpyType::F32);
    const std::vector<float> expected = g.toFloats();
    const std::vector<float> actual = loadPreparedImage(goldenDir() + "/" + c.image, c.h, c.w);
    ASSERT_EQ(actual.size(), expected.size());
    const double d = maxDiff255(actual, expected);
    size_t differing = 0;
    for (size_t i = 0; i < actual.size(); ++i) differing += actual[i] != expected[i];
    std::printf("  %-24s %3dx%-3d max |C++ - PIL| = %g/255, %zu of %zu values differ\n", c.name.c_str(), c.h, c.w, d,
                differing, actual.size());
    worst = std::max(worst, d);
    EXPECT_EQ(differing, 0u);
  }
  std::printf("  worst case: %g/255\n", worst);
}

// loadImageRGB gives what PIL's convert("RGB") gives (grey replicated, alpha dropped, JPEG
// decoded by the same libjpeg).
TEST(ImagePrep, LoaderMatchesPilConvert) {
  std::vector<std::string> images;
  for (const auto& c : readCases())
    if (std::find(images.begin(), images.end(), c.image) == images.end()) images.push_back(c.image);
  for (const auto& image : images) {
    SCOPED_TRACE(image);
    const RgbImage rgb = loadImageRGB(goldenDir() + "/" + image);
    const std::string stem = fs::path(image).stem().string();
    const NpyArray g = readNpy(goldenDir() + "/" + stem + ".rgb.npy", {rgb.height, rgb.width, 3});
    const std::vector<int64_t> expected = g.toInt64s();
    ASSERT_EQ(expected.size(), rgb.pixels.size());
    size_t differing = 0;
    for (size_t i = 0; i < expected.size(); ++i) differing += int64_t(rgb.pixels[i]) != expected[i];
    EXPECT_EQ(differing, 0u);
  }
}

// Constant images stay exactly 0 and 1 through the resize (the weights of every output pixel
// sum to one within the fixed-point rounding).
TEST(ImagePrep, ConstantImagesGiveExactlyZeroAndOne) {
  for (const auto& [value, expected] : {std::pair{uint8_t(0), 0.0f}, std::pair{uint8_t(255), 1.0f}})
    for (const auto& [w, h, H, W] : {std::tuple{50, 70, 64, 64}, std::tuple{77, 33, 40, 40}, std::tuple{640, 480, 224, 224},
                                     std::tuple{13, 9, 100, 80}}) {
      RgbImage img;
      img.width = w;
      img.height = h;
      img.pixels.assign(size_t(w) * h * 3, value);
      const auto x = prepareImage(img, H, W);
      ASSERT_EQ(x.size(), size_t(3) * H * W);
      EXPECT_TRUE(std::all_of(x.begin(), x.end(), [want = expected](float v) { return v == want; }))
          << int(value) << " " << w << "x" << h << " -> " << H << "x" << W;
    }
  // And the PIL-made files.
  const auto black = loadPreparedImage(goldenDir() + "/black_50x70.png", 64, 64);
  const auto white = loadPreparedImage(goldenDir() + "/white_77x33.png", 40, 40);
  EXPECT_TRUE(std::all_of(black.begin(), black.end(), [](float v) { return v == 0.0f; }));
  EXPECT_TRUE(std::all_of(white.begin(), white.end(), [](float v) { return v == 1.0f; }));
}

// The crop geometry of the reference, including Python's round half to even.
TEST(ImagePrep, CropGeometry) {
  auto g = cropGeometry(150, 180, 64, 64);  // shorter side (w) becomes 64
  EXPECT_EQ(g.resizedWidth, 64);
  EXPECT_EQ(g.resizedHeight, 77);  // round(180 * 64 / 150) = round(76.8)
  EXPECT_EQ(g.left, 0);
  EXPECT_EQ(g.top, 6);
  g = cropGeometry(37, 61, 96, 96);  // upscale
  EXPECT_EQ(g.resizedWidth, 96);
  EXPECT_EQ(g.resizedHeight, 158);
  EXPECT_EQ(g.top, 31);
  g = cropGeometry(4, 10, 1, 1);  // 10 * 0.25 = 2.5 -> 2 (half to even)
  EXPECT_EQ(g.resizedWidth, 1);
  EXPECT_EQ(g.resizedHeight, 2);
  g = cropGeometry(4, 14, 1, 1);  // 3.5 -> 4
  EXPECT_EQ(g.resizedHeight, 4);
  g = cropGeometry(48, 48, 48, 48);
  EXPECT_EQ(g.resizedWidth, 48);
  EXPECT_EQ(g.resizedHeight, 48);
  EXPECT_THROW(cropGeometry(0, 10, 4, 4), Error);
}

// Up- and downscaling give the requested sizes; a same-size resize is the identity.
TEST(ImagePrep, ResizeSizes) {
  const RgbImage src = loadImageRGB(goldenDir() + "/rgb_37x61.png");
  ASSERT_EQ(src.width, 37);
  ASSERT_EQ(src.height, 61);
  for (const auto& [w, h] : {std::pair{100, 7}, std::pair{5, 200}, std::pair{1, 1}, std::pair{37, 61}}) {
    const RgbImage r = resizeLanczos(src, w, h);
    EXPECT_EQ(r.width, w);
    EXPECT_EQ(r.height, h);
    EXPECT_EQ(r.pixels.size(), size_t(w) * h * 3);
  }
  EXPECT_EQ(resizeLanczos(src, 37, 61).pixels, src.pixels);
  EXPECT_THROW(resizeLanczos(src, 0, 5), Error);
}

TEST(ImagePrep, ErrorsForMissingAndUnreadableFiles) {
  auto message = [](const std::string& path) -> std::string {
    try {
      loadImageRGB(path);
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  };
  const std::string missing = goldenDir() + "/no_such_image.png";
  std::string m = message(missing);
  EXPECT_NE(m.find("image not found: " + missing), std::string::npos) << m;
  EXPECT_TRUE(oneLine(m)) << m;
  for (const char* bad : {"not_an_image.png", "truncated.png", "cases.txt"}) {
    m = message(goldenDir() + "/" + bad);
    EXPECT_NE(m.find("cannot read image"), std::string::npos) << bad << ": " << m;
    EXPECT_NE(m.find(bad), std::string::npos) << m;
    EXPECT_TRUE(oneLine(m)) << m;
    std::printf("  %s: %s\n", bad, m.c_str());
  }
  m = message(goldenDir());
  EXPECT_NE(m.find("cannot read image"), std::string::npos) << m;
  EXPECT_THROW(loadPreparedImage(missing, 64, 64), Error);
}

// writePng: floor(clip(x, 0, 1) * 255 + 0.5), RGB from [3, H, W] and grey from [H, W]; the
// temporary file is renamed away.
TEST(ImagePrep, WritePngRoundsLikeTheReference) {
  const fs::path dir = fs::path(SPAR_TEST_OUT_DIR) / "image_write";
  fs::remove_all(dir);
  fs::create_directories(dir);
  EXPECT_EQ(toUint8(-0.5), 0);
  EXPECT_EQ(toUint8(std::nan("")), 0);
  EXPECT_EQ(toUint8(2.0), 255);
  EXPECT_EQ(toUint8(0.5 / 255.0), 1);          // half rounds up
  EXPECT_EQ(toUint8(0.4999 / 255.0), 0);
  EXPECT_EQ(toUint8(127.5 / 255.0), 128);
  EXPECT_EQ(toUint8(1.0), 255);

  const int H = 7, W = 11;
  std::vector<float> chw(3 * H * W);
  for (size_t i = 0; i < chw.size(); ++i) chw[i] = float(int(i % 300) - 20) / 255.0f + (i % 2 ? 0.49f : 0.51f) / 255.0f;
  const std::string rgbPath = (dir / "rgb.png").string();
  writePng(rgbPath, chw, 3, H, W);
  const RgbImage back = loadImageRGB(rgbPath);
  ASSERT_EQ(back.width, W);
  ASSERT_EQ(back.height, H);
  for (int c = 0; c < 3; ++c)
    for (int p = 0; p < H * W; ++p) ASSERT_EQ(back.pixels[p * 3 + c], toUint8(chw[c * H * W + p])) << c << " " << p;

  std::vector<float> grey(H * W);
  for (size_t i = 0; i < grey.size(); ++i) grey[i] = float(i) / float(grey.size() - 1);
  const std::string greyPath = (dir / "grey.png").string();
  writePng(greyPath, grey, 1, H, W);
  const RgbImage g = loadImageRGB(greyPath);
  for (int p = 0; p < H * W; ++p)
    for (int c = 0; c < 3; ++c) ASSERT_EQ(g.pixels[p * 3 + c], toUint8(grey[p]));

  writePng((dir / "img.png").string(), back);  // RgbImage as it is
  EXPECT_EQ(loadImageRGB((dir / "img.png").string()).pixels, back.pixels);

  // Overwriting works, and nothing but the three PNGs is left behind.
  writePng(rgbPath, chw, 3, H, W);
  size_t files = 0;
  for (const auto& e : fs::directory_iterator(dir)) files += e.is_regular_file();
  EXPECT_EQ(files, 3u);

  EXPECT_THROW(writePng((dir / "no_dir" / "x.png").string(), grey, 1, H, W), Error);
  EXPECT_THROW(writePng((dir / "bad.png").string(), grey, 3, H, W), Error);  // wrong size
  EXPECT_THROW(writePng((dir / "bad.png").string(), grey.data(), 2, H, W), Error);
}

}  // namespace
}  // namespace spar::test
