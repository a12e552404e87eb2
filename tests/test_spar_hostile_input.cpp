// Hostile or broken input to the built `spar`, each a one-line error with no other line on
// stderr (libpng's own messages folded into it), exit 1, and no output directory: truncated PNGs,
// headers claiming 2^31-1 rows or 100000 x 100000 pixels (refused from the header, before any
// decoding), and output locations that cannot be written (refused before any work).
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "imaging/image_prep.h"
#include "tests/golden_support.h"
#include "tests/cli_test_support.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;

const fs::path& scratch() { return scratchDir("spar_hostile"); }

std::string bytesOf(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), {}};
}

fs::path writeFile(const std::string& name, const std::string& bytes) {
  const fs::path p = scratch() / name;
  std::ofstream(p, std::ios::binary) << bytes;
  return p;
}

uint32_t crc32(const std::string& s, size_t begin, size_t end) {
  uint32_t c = 0xffffffffu;
  for (size_t i = begin; i < end; ++i) {
    c ^= uint8_t(s[i]);
    for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xedb88320u & (0u - (c & 1u)));
  }
  return ~c;
}

// The PNG with its IHDR width and height replaced (CRC fixed, so only the size is wrong).
std::string withSize(std::string png, uint32_t width, uint32_t height) {
  auto put = [&](size_t at, uint32_t v) {
    for (int i = 0; i < 4; ++i) png[at + i] = char((v >> (24 - 8 * i)) & 0xff);
  };
  put(16, width);
  put(20, height);
  put(29, crc32(png, 12, 29));  // over "IHDR" and its 13 bytes
  return png;
}

CommandResult render(const std::vector<std::string>& frames, const fs::path& out) {
  std::vector<std::string> argv = {SPAR_CLI, "render", "--model", goldenPath("tiny.spar"), "--frames"};
  argv.insert(argv.end(), frames.begin(), frames.end());
  for (const char* a : {"--inputs", "0,2"}) argv.push_back(a);
  argv.push_back("--out");
  argv.push_back(out.string());
  return runValidated(argv, scratch());
}

void expectOneErrorLine(const CommandResult& r, const std::string& expected) {
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  EXPECT_EQ(r.err.rfind("spar: error: ", 0), 0u) << r.err;
  EXPECT_NE(r.err.find(expected), std::string::npos) << "expected '" << expected << "' in: " << r.err;
}

TEST(spar_hostile, BrokenImagesAreOneLine) {
  const std::string png = bytesOf(goldenPath("frame_0.png"));
  const std::string f1 = goldenPath("frame_1.png"), f2 = goldenPath("frame_2.png");
  const fs::path out = scratch() / "out";
  const struct {
    std::string name, bytes, expected;
  } cases[] = {
      {"truncated.png", png.substr(0, png.size() / 2), "truncated.png"},
      {"tall.png", withSize(png, 160, 0x7fffffffu), "tall.png: PNG read error: Invalid IHDR data"},
      {"huge.png", withSize(png, 100000, 100000), "100000x100000 pixels"},
      {"garbage.png", std::string(200, 'x'), "garbage.png"},
  };
  for (const auto& c : cases) {
    fs::remove_all(out);
    const fs::path p = writeFile(c.name, c.bytes);
    const CommandResult r = render({p.string(), f1, f2}, out);
    expectOneErrorLine(r, c.expected);
    EXPECT_FALSE(fs::exists(out)) << c.name;
  }
}

// PNGs are read and written with libpng; OpenImageIO, for other formats, is loaded with the
// image-file module on first use (imaging/image_files.h): spar does not link it, a PNG-only run
// does not need it, and a module that cannot be found is one line naming where it was looked for.
TEST(spar_hostile, ImageModuleIsLoadedOnUseAndItsAbsenceIsOneLine) {
  const CommandResult elf = runCommand({"readelf", "-d", SPAR_CLI}, scratch());
  ASSERT_EQ(elf.code, 0) << elf.err;
  EXPECT_NE(elf.out.find("libvulkan"), std::string::npos) << elf.out;
  EXPECT_EQ(elf.out.find("OpenImageIO"), std::string::npos) << elf.out;
  const fs::path out = scratch() / "no_module", missing = scratch() / "nowhere" / "spar_image_files.so";
  const std::string noModule = "SPAR_IMAGE_FILES_MODULE=" + missing.string();
  auto renderWithout = [&](const std::string& first) {
    fs::remove_all(out);
    return runValidated({SPAR_CLI, "render", "--model", goldenPath("tiny.spar"), "--frames", first,
                         goldenPath("frame_1.png"), goldenPath("frame_2.png"), "--inputs", "0,2", "--out", out.string()},
                        scratch(), noModule);
  };
  const CommandResult png = renderWithout(goldenPath("frame_0.png"));
  EXPECT_EQ(png.code, 0) << png.err;
  EXPECT_TRUE(fs::exists(out / "view_00.png"));
  const CommandResult other = renderWithout(writeFile("not_a_png.bmp", std::string(64, 'x')).string());
  expectOneErrorLine(other, "not_a_png.bmp: cannot read or write image files: spar_image_files.so not found (looked at " +
                                missing.string());
  EXPECT_FALSE(fs::exists(out));
}

TEST(spar_hostile, UnwritableOutputIsRefusedBeforeWork) {
  const std::vector<std::string> frames = {goldenPath("frame_0.png"), goldenPath("frame_1.png"),
                                           goldenPath("frame_2.png")};
  const fs::path file = writeFile("a_file", "x");
  // One line and nothing else: no progress line, so refused before the device was opened.
  expectOneErrorLine(render(frames, "/proc/spar_out"), "cannot write in /proc");
  expectOneErrorLine(render(frames, file / "out"), "a_file is a file, not a directory");
  expectOneErrorLine(render(frames, file / "deeper" / "out"), "a_file is a file, not a directory");
}

}  // namespace
}  // namespace spar::test

namespace spar::test {
namespace {

// Legal but likely a mistake: the run goes on (exit 0) and says so, once, on one line.
size_t countOf(const std::string& text, const std::string& what) {
  size_t n = 0;
  for (size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++n;
  return n;
}

TEST(spar_hostile, LikelyMistakesAreOneLineWarnings) {
  // A 1x1 image among the inputs.
  const fs::path tiny = scratch() / "one_pixel.png";
  const std::vector<float> pixel = {0.5f, 0.5f, 0.5f};
  writePng(tiny.string(), pixel, 3, 1, 1);
  fs::path out = scratch() / "warn_tiny";
  fs::remove_all(out);
  CommandResult r = render({tiny.string(), goldenPath("frame_1.png"), goldenPath("frame_2.png")}, out);
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(countOf(r.err, "spar: warning: "), 1u) << r.err;
  EXPECT_NE(r.err.find("one_pixel.png is 1x1 pixels, far smaller than the 128x128 the model runs at"), std::string::npos)
      << r.err;

  // 17 views of a model trained with 5 a scene (the fixture's num_views).
  std::vector<std::string> frames;
  for (int i = 0; i < 17; ++i) frames.push_back(goldenPath("frame_" + std::to_string(i % 5) + ".png"));
  out = scratch() / "warn_views";
  fs::remove_all(out);
  r = render(frames, out);
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(countOf(r.err, "spar: warning: "), 1u) << r.err;
  EXPECT_NE(r.err.find("17 views (2 inputs): the model was trained with"), std::string::npos) << r.err;

  // Prompts: one over 77 tokens, and 25 labels.
  std::string labels = "a";
  for (int i = 0; i < 90; ++i) labels += " very";
  labels += " long chair";
  for (int i = 0; i < 24; ++i) labels += ",label" + std::to_string(i);
  out = scratch() / "warn_labels";
  fs::remove_all(out);
  std::vector<std::string> argv = {SPAR_CLI, "render", "--model", semanticGoldenPath("tiny_semantic.spar"), "--frames"};
  for (int i = 0; i < 5; ++i) argv.push_back(goldenPath("frame_" + std::to_string(i) + ".png"));
  for (const char* a : {"--inputs", "0,2,4", "--labels"}) argv.push_back(a);
  argv.push_back(labels);
  argv.push_back("--out");
  argv.push_back(out.string());
  r = runValidated(argv, scratch());
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(countOf(r.err, "spar: warning: "), 2u) << r.err;
  EXPECT_NE(r.err.find("tokens: CLIP reads the first 77"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("25 labels: the palette has 20"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace spar::test
