// spar render --format: the float view formats hold the engine's RGB as computed (through the
// built `spar` on the tiny photometric fixture): npy as [3, H, W] float32, EXR float32 equal to
// it to 1e-7, EXR half equal to its fp16 rounding, and the default PNG its 8-bit rounding.
#include <gtest/gtest.h>

#include <OpenImageIO/imageio.h>

#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include "engine/half.h"
#include "formats/npy.h"
#include "tests/golden_support.h"
#include "tests/cli_test_support.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;

const fs::path& scratch() { return scratchDir("spar_formats"); }

fs::path render(const std::string& format) {
  const fs::path out = scratch() / ("out_" + format);
  fs::remove_all(out);
  std::vector<std::string> argv = {SPAR_CLI, "render", "--model", goldenPath("tiny.spar"), "--frames"};
  for (int i = 0; i < 5; ++i) argv.push_back(goldenPath("frame_" + std::to_string(i) + ".png"));
  for (const char* a : {"--inputs", "0,2,4", "--format"}) argv.push_back(a);
  argv.push_back(format);
  argv.push_back("--out");
  argv.push_back(out.string());
  const CommandResult r = runValidated(argv, scratch());
  EXPECT_EQ(r.code, 0) << r.err;
  return out;
}

// [3, H, W] from an image file (any channel type, read as float).
std::vector<float> readPlanes(const fs::path& p, int& w, int& h, OIIO::TypeDesc* stored = nullptr) {
  auto in = OIIO::ImageInput::open(p.string());
  EXPECT_TRUE(in) << p;
  if (!in) return {};
  const OIIO::ImageSpec& spec = in->spec();
  w = spec.width;
  h = spec.height;
  if (stored) *stored = spec.format;
  std::vector<float> hwc(size_t(w) * h * spec.nchannels);
  EXPECT_TRUE(in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, hwc.data()));
  std::vector<float> chw(size_t(w) * h * 3);
  for (size_t i = 0; i < size_t(w) * h; ++i)
    for (int c = 0; c < 3; ++c) chw[size_t(c) * w * h + i] = hwc[i * spec.nchannels + c];
  return chw;
}

TEST(spar_formats, FloatViewsHoldTheRgbAsComputed) {
  const fs::path npyDir = render("npy"), exrDir = render("exr"), halfDir = render("exr16"), pngDir = render("png");
  for (const char* view : {"view_00", "view_01"}) {
    const std::vector<float> rgb = readNpy((npyDir / (std::string(view) + ".npy")).string(), {3, 128, 128}).toFloats();
    ASSERT_EQ(rgb.size(), size_t(3 * 128 * 128));
    int w = 0, h = 0;
    OIIO::TypeDesc type;
    const std::vector<float> exr = readPlanes(exrDir / (std::string(view) + ".exr"), w, h, &type);
    EXPECT_EQ(w, 128);
    EXPECT_EQ(type, OIIO::TypeDesc::FLOAT);
    const std::vector<float> half = readPlanes(halfDir / (std::string(view) + ".exr"), w, h, &type);
    EXPECT_EQ(type, OIIO::TypeDesc::HALF);
    const std::vector<float> png = readPlanes(pngDir / (std::string(view) + ".png"), w, h);
    ASSERT_EQ(exr.size(), rgb.size());
    ASSERT_EQ(half.size(), rgb.size());
    ASSERT_EQ(png.size(), rgb.size());
    double maxExr = 0, maxPng = 0;
    size_t halfMismatch = 0, distinct = 0;
    for (size_t i = 0; i < rgb.size(); ++i) {
      maxExr = std::max(maxExr, double(std::abs(exr[i] - rgb[i])));
      halfMismatch += half[i] != halfToFloat(floatToHalf(rgb[i]));
      maxPng = std::max(maxPng, std::abs(double(png[i]) * 255.0 - double(rgb[i]) * 255.0));
      distinct += i > 0 && rgb[i] != rgb[i - 1];
    }
    EXPECT_LE(maxExr, 1e-7) << view;
    EXPECT_EQ(halfMismatch, 0u) << view;
    EXPECT_LE(maxPng, 0.5 + 1e-3) << view;  // the 8-bit PNG is the rounding of the same values
    EXPECT_GT(distinct, rgb.size() / 4) << "a view of few distinct values proves little";
  }
  EXPECT_FALSE(fs::exists(npyDir / "view_00.png"));
}

}  // namespace
}  // namespace spar::test
