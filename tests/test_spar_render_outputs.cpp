// The --path animation and long paths of `spar render` (tools/spar/render_outputs.h,
// animation.h), through the built `spar` (SPAR_CLI) on the tiny photometric fixture, with the
// validation layer and synchronization validation on (runValidated):
//  - with ffmpeg installed (scripts/setup/install-deps.sh) the default --animation auto writes path.mp4:
//    H.264, one frame per view, the views' pixels up to H.264's loss; report.json and the last
//    progress line say which file was written and how;
//  - without ffmpeg (SPAR_FFMPEG naming none) auto writes path.gif and says why; --animation mp4 is
//    then refused before any work; an ffmpeg that fails gives one error line with its message
//    and no output directory;
//  - odd frame sizes are padded to even ones (yuv420p needs them), through FfmpegVideo itself;
//  - a long --path is written as it is rendered: peak memory does not grow with the path's length.
// The suite is named "spar_render_outputs" (`ctest -R spar_render_outputs`).
#include <gtest/gtest.h>

#include <sys/resource.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "spar/error.h"
#include "formats/npy.h"
#include "imaging/image_prep.h"
#include "tools/spar/ffmpeg_video.h"
#include "tests/golden_support.h"
#include "tests/cli_test_support.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

const fs::path& scratch() { return scratchDir("spar_render_outputs"); }

// `spar render` of the tiny fixture from three input frames with `extra` options into `out`.
CommandResult render(const fs::path& out, const std::vector<std::string>& extra, const std::string& env = "") {
  fs::remove_all(out);
  std::vector<std::string> argv = {SPAR_CLI, "render", "--model", goldenPath("tiny.spar"), "--images"};
  for (int i : {0, 2, 4}) argv.push_back(goldenPath("frame_" + std::to_string(i) + ".png"));
  argv.insert(argv.end(), extra.begin(), extra.end());
  argv.push_back("--out");
  argv.push_back(out.string());
  return runValidated(argv, scratch(), env);
}

json readJson(const fs::path& p) {
  std::ifstream in(p);
  return json::parse(in);
}

std::string lastLine(const std::string& text) {
  const std::vector<std::string> lines = CommandResult{0, "", text}.errLines();
  return lines.empty() ? "" : lines.back();
}

void expectNoOutput(const fs::path& out) {
  EXPECT_FALSE(fs::exists(out)) << out;
  for (const auto& e : fs::directory_iterator(out.parent_path()))
    EXPECT_EQ(e.path().filename().string().rfind(out.filename().string() + ".tmp", 0), std::string::npos) << e.path();
}

// The video's frames decoded by ffmpeg as rgb24 (frames x H x W x 3).
std::vector<uint8_t> decodeFrames(const fs::path& video) {
  const fs::path raw = scratch() / "decoded.rgb";
  const CommandResult r = runCommand({"ffmpeg", "-v", "error", "-y", "-i", video.string(), "-f", "rawvideo",
                                      "-pix_fmt", "rgb24", raw.string()},
                                     scratch());
  EXPECT_EQ(r.code, 0) << r.err;
  const std::string bytes = readText(raw);
  return std::vector<uint8_t>(bytes.begin(), bytes.end());
}

TEST(spar_render_outputs, PathIsAnH264VideoWhenFfmpegIsInstalled) {
  const fs::path out = scratch() / "mp4";
  const CommandResult r = render(out, {"--path", "5"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_FALSE(fs::exists(out / "path.gif"));
  const VideoInfo v = probeVideo(out / "path.mp4", scratch());
  EXPECT_EQ(v.codec, "h264");
  EXPECT_EQ(v.frames, 5);
  EXPECT_EQ(v.width, 128);
  EXPECT_EQ(v.height, 128);
  EXPECT_FALSE(fs::exists(out / "path.mp4.log"));  // ffmpeg's log is kept only to explain a failure
  const json report = readJson(out / "report.json");
  EXPECT_EQ(report["animation"]["file"], "path.mp4");
  EXPECT_NE(report["animation"]["how"].get<std::string>().find("H.264"), std::string::npos) << report.dump();
  EXPECT_NE(lastLine(r.err).find("path.mp4: H.264"), std::string::npos) << r.err;

  // Each frame is its view up to H.264's loss. yuv420p keeps luma at full resolution and halves
  // chroma's, which the fixture's noisy colours feel: compare luma (the tiny fixture's path views
  // differ too little from each other to check the frames' order this way).
  const std::vector<uint8_t> frames = decodeFrames(out / "path.mp4");
  const size_t pixels = size_t(128) * 128;
  ASSERT_EQ(frames.size(), 5 * pixels * 3);
  auto luma = [](const uint8_t* rgb) { return 0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2]; };
  std::vector<RgbImage> views;
  for (int j = 0; j < 5; ++j) views.push_back(loadImageRGB((out / ("view_0" + std::to_string(j) + ".png")).string()));
  for (int f = 0; f < 5; ++f) {
    std::vector<double> diff(5, 0.0);
    for (int j = 0; j < 5; ++j) {
      ASSERT_EQ(views[j].pixels.size(), pixels * 3);
      for (size_t i = 0; i < pixels; ++i)
        diff[j] += std::abs(luma(&frames[(f * pixels + i) * 3]) - luma(&views[j].pixels[i * 3])) / double(pixels);
    }
    EXPECT_LE(diff[f], 2.5) << "frame " << f << ": mean luma difference to its view";
  }
}

TEST(spar_render_outputs, WithoutFfmpegAutoWritesAGifAndSaysWhy) {
  const fs::path out = scratch() / "gif";
  const CommandResult r = render(out, {"--path", "3"}, "SPAR_FFMPEG=");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_FALSE(fs::exists(out / "path.mp4"));
  EXPECT_TRUE(fs::exists(out / "path.gif"));
  const json report = readJson(out / "report.json");
  EXPECT_EQ(report["animation"]["file"], "path.gif");
  EXPECT_NE(report["animation"]["how"].get<std::string>().find("ffmpeg not found"), std::string::npos)
      << report.dump();
  EXPECT_NE(lastLine(r.err).find("path.gif: GIF (ffmpeg not found"), std::string::npos) << r.err;
}

TEST(spar_render_outputs, Mp4WithoutFfmpegIsRefusedBeforeWork) {
  const fs::path out = scratch() / "no_ffmpeg";
  const CommandResult r = render(out, {"--path", "3", "--animation", "mp4"}, "SPAR_FFMPEG=/nonexistent/ffmpeg");
  EXPECT_EQ(r.code, 1) << r.err;
  ASSERT_EQ(r.errLines().size(), 1u) << r.err;  // refused before any progress line
  EXPECT_NE(r.err.find("spar: error: --animation mp4 needs ffmpeg"), std::string::npos) << r.err;
  expectNoOutput(out);
}

TEST(spar_render_outputs, FailingFfmpegIsOneLineWithItsMessageAndNoOutput) {
  const fs::path fake = scratch() / "fake_ffmpeg";
  std::ofstream(fake) << "#!/bin/sh\necho 'Unknown encoder libx264' >&2\nexit 1\n";
  fs::permissions(fake, fs::perms::owner_all);
  const fs::path out = scratch() / "failing";
  const CommandResult r = render(out, {"--path", "3"}, "SPAR_FFMPEG=" + shellQuote(fake.string()));
  EXPECT_EQ(r.code, 1) << r.err;
  const std::string last = lastLine(r.err);
  EXPECT_EQ(last.rfind("spar: error: cannot write ", 0), 0u) << r.err;
  EXPECT_NE(last.find("(ffmpeg: Unknown encoder libx264)"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("\nUnknown encoder"), std::string::npos) << r.err;  // not printed on its own
  expectNoOutput(out);
}

TEST(spar_render_outputs, OddFrameSizesArePaddedToEven) {
  const std::string ffmpeg = cli::findFfmpeg();
  ASSERT_FALSE(ffmpeg.empty()) << "ffmpeg is installed by scripts/setup/install-deps.sh";
  const fs::path path = scratch() / "odd.mp4";
  {
    cli::FfmpegVideo video(ffmpeg, path.string(), 4);
    for (int f = 0; f < 3; ++f) {
      RgbImage frame{7, 5, std::vector<uint8_t>(7 * 5 * 3, uint8_t(40 * f))};
      video.add(frame);
    }
    RgbImage wrong{8, 5, std::vector<uint8_t>(8 * 5 * 3)};
    EXPECT_THROW(video.add(wrong), Error);
    video.finish();
  }
  const VideoInfo v = probeVideo(path, scratch());
  EXPECT_EQ(v.width, 8);
  EXPECT_EQ(v.height, 6);
  EXPECT_EQ(v.frames, 3);
}

// Peak resident memory of the children waited for so far (getrusage keeps the maximum).
long childPeakKiB() {
  rusage u{};
  getrusage(RUSAGE_CHILDREN, &u);
  return u.ru_maxrss;
}

TEST(spar_render_outputs, LongPathMemoryDoesNotGrowWithItsLength) {
  // 256x256 views: the 240-view path holds 240 x 3 x 256 x 256 floats = 189 MB of RGB, and as
  // much again of frames, if it kept them until the end; written as rendered, it holds one chunk.
  const fs::path shortOut = scratch() / "short_path", longOut = scratch() / "long_path";
  CommandResult r = render(shortOut, {"--path", "8", "--size", "256x256"});
  ASSERT_EQ(r.code, 0) << r.err;
  const long shortPeak = childPeakKiB();
  r = render(longOut, {"--path", "240", "--size", "256x256"});
  ASSERT_EQ(r.code, 0) << r.err;
  const long longPeak = childPeakKiB();
  std::printf("peak RSS: --path 8 %.1f MB, --path 240 %.1f MB\n", shortPeak / 1024.0, longPeak / 1024.0);
  EXPECT_TRUE(fs::exists(longOut / "view_239.png"));
  EXPECT_EQ(probeVideo(longOut / "path.mp4", scratch()).frames, 240);
  EXPECT_LT(longPeak - shortPeak, 48 * 1024) << "KiB";
}

}  // namespace
}  // namespace spar::test
