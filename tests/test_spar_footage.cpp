// `spar render` on footage nobody here made (Debian's opencv-doc: vtest.avi, people walking past
// a fixed camera; graf1.png / graf3.png, one wall from two viewpoints) and on the video files a
// user may hold, through the built `spar` (SPAR_CLI) under the validation layer. The shipped
// model was trained on synthetic rooms, so the run is judged, not the picture: the files and
// their shapes, finite cameras, motion masks that are not one value for the walking people, no
// warnings; and every hostile video (corrupt, truncated, audio only, no frames, a directory, a
// time past the end) is one error line, exit 1, nothing written.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "imaging/image_prep.h"
#include "tests/cli_test_support.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

const fs::path kOpencvData = "/usr/share/doc/opencv-doc/examples/data";
const fs::path kModel = fs::path(SPAR_SOURCE_DIR) / "data" / "spar_rooms.spar";

const fs::path& scratch() { return scratchDir("spar_footage"); }

CommandResult spar(const std::vector<std::string>& args) {
  std::vector<std::string> argv = {SPAR_CLI};
  argv.insert(argv.end(), args.begin(), args.end());
  return runValidated(argv, scratch());
}

json readJson(const fs::path& p) {
  std::ifstream in(p);
  return json::parse(in);
}

// Every estimated camera in cameras.json finite, with a rotation (its 3x3 of c2w_opencv) of
// determinant 1.
void expectValidCameras(const fs::path& out, size_t views) {
  const json cams = readJson(out / "cameras.json");
  ASSERT_EQ(cams.at("frames").size(), views);
  for (const auto& f : cams.at("frames")) {
    const auto m = f.at("c2w_opencv").get<std::vector<std::vector<double>>>();
    for (const auto& row : m)
      for (double x : row) EXPECT_TRUE(std::isfinite(x));
    const double det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
                       m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    EXPECT_NEAR(det, 1.0, 1e-4);
  }
}

// The share of dynamic pixels in a mask_XX.png.
double dynamicShare(const fs::path& mask) {
  const RgbImage m = loadImageRGB(mask.string());
  size_t on = 0;
  for (size_t i = 0; i < m.pixels.size(); i += 3) on += m.pixels[i] > 127;
  return double(on) / double(m.pixels.size() / 3);
}

TEST(spar_footage, PeopleWalkingPastAFixedCamera) {
  // The README's command: the model's 8 views spread over the clip, its 2 inputs spread evenly.
  const fs::path video = kOpencvData / "vtest.avi", out = scratch() / "vtest";
  fs::remove_all(out);
  CommandResult r = spar({"render", "--model", kModel.string(), "--video", video.string(), "--out", out.string()});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.err.find("warning"), std::string::npos) << r.err;
  for (int j = 0; j < 6; ++j) EXPECT_TRUE(fs::exists(out / ("view_0" + std::to_string(j) + ".png"))) << j;
  EXPECT_TRUE(fs::exists(out / "mask_01.png"));
  expectValidCameras(out, 8);
  const json cams = readJson(out / "cameras.json");
  EXPECT_NE(cams["frames"][0]["file_path"].get<std::string>().find("vtest.avi@4.969s"), std::string::npos);

  // Three frames 0.4 s apart, two of them inputs: the walking woman in front moves, the rest
  // does not. Each input's mask holds both values.
  const fs::path close = scratch() / "vtest_close";
  fs::remove_all(close);
  r = spar({"render", "--model", kModel.string(), "--video", video.string(), "--video-at", "62,62.4,62.8", "--inputs",
            "0,1", "--out", close.string()});
  ASSERT_EQ(r.code, 0) << r.err;
  for (const char* m : {"mask_00.png", "mask_01.png"}) {
    const double share = dynamicShare(close / m);
    EXPECT_GT(share, 0.005) << m;
    EXPECT_LT(share, 0.5) << m;
  }
  const RgbImage view = loadImageRGB((close / "view_00.png").string());
  EXPECT_EQ(view.width, 128);
  EXPECT_EQ(view.height, 128);
}

TEST(spar_footage, OneWallFromTwoViewpoints) {
  // graf1 and graf3 (800x640): inputs only, a path of 3 cameras between them.
  const fs::path out = scratch() / "graf";
  fs::remove_all(out);
  const CommandResult r = spar({"render", "--model", kModel.string(), "--images", (kOpencvData / "graf1.png").string(),
                                (kOpencvData / "graf3.png").string(), "--path", "3", "--animation", "gif", "--out",
                                out.string()});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.err.find("warning"), std::string::npos) << r.err;
  for (const char* f : {"view_00.png", "view_02.png", "path.gif", "mask_00.png", "mask_01.png", "report.json"})
    EXPECT_TRUE(fs::exists(out / f)) << f;
  expectValidCameras(out, 2);
}

// A clip made here with ffmpeg: 2 s of a test pattern, 96x64, moov atom first.
fs::path makeClip(const std::string& name, const std::vector<std::string>& extra = {}) {
  const fs::path p = scratch() / name;
  std::vector<std::string> argv = {"ffmpeg", "-v", "error", "-y", "-f", "lavfi", "-i", "testsrc=size=96x64:rate=10:duration=2",
                                   "-c:v", "libx264", "-pix_fmt", "yuv420p", "-movflags", "+faststart"};
  argv.insert(argv.end(), extra.begin(), extra.end());
  argv.push_back(p.string());
  const CommandResult r = runCommand(argv, scratch());
  EXPECT_EQ(r.code, 0) << r.err;
  return p;
}

TEST(spar_footage, HostileVideosAreOneLineAndNothingWritten) {
  const fs::path plain = makeClip("plain.mp4");
  std::string bytes = readText(plain);
  const fs::path truncated = scratch() / "truncated.mp4", corrupt = scratch() / "corrupt.mp4",
                 headless = scratch() / "headless.mp4", audio = scratch() / "audio.m4a", dir = scratch() / "dir.mp4",
                 empty = scratch() / "empty.mkv";
  std::ofstream(truncated, std::ios::binary) << bytes.substr(0, bytes.size() * 6 / 10);  // header kept, frames cut
  std::ofstream(headless, std::ios::binary) << bytes.substr(bytes.size() / 2);
  std::string noise(5000, '\0');
  for (size_t i = 0; i < noise.size(); ++i) noise[i] = char((i * 2654435761u) >> 13);
  std::ofstream(corrupt, std::ios::binary) << noise;
  fs::create_directories(dir);
  ASSERT_EQ(runCommand({"ffmpeg", "-v", "error", "-y", "-f", "lavfi", "-i", "sine=duration=1", audio.string()}, scratch()).code, 0);
  ASSERT_EQ(runCommand({"ffmpeg", "-v", "error", "-y", "-f", "lavfi", "-i", "testsrc=size=96x64:rate=10:duration=1",
                        "-frames:v", "0", "-c:v", "ffv1", empty.string()}, scratch()).code, 0);
  const std::vector<std::pair<fs::path, std::string>> cases = {
      {truncated, "no frame at"},      {headless, "cannot read video"}, {corrupt, "cannot read video"},
      {audio, "no video stream"},      {dir, "it is a directory"},      {empty, "cannot read video"},
      {scratch() / "missing.mp4", "video not found"},
  };
  for (const auto& [video, message] : cases) {
    const fs::path out = scratch() / "hostile_out";
    fs::remove_all(out);
    const CommandResult r = spar({"render", "--model", kModel.string(), "--video", video.string(), "--out", out.string()});
    EXPECT_EQ(r.code, 1) << video << r.err;
    ASSERT_EQ(r.errLines().size(), 1u) << video << r.err;
    EXPECT_EQ(r.errLines()[0].rfind("spar: error: ", 0), 0u) << r.err;
    EXPECT_NE(r.err.find(message), std::string::npos) << video << ": " << r.err;
    EXPECT_EQ(r.err.find(" @ 0x"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(out)) << video;
  }
  // a time past the end; --video with --frames (a usage error, exit 2)
  const fs::path out = scratch() / "hostile_out";
  CommandResult r = spar({"render", "--model", kModel.string(), "--video", plain.string(), "--video-at", "0.5,1,7",
                          "--inputs", "0,1", "--out", out.string()});
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_NE(r.err.find("is 2.000 s long: no frame at 7.000 s"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(out));
  r = spar({"render", "--model", kModel.string(), "--video", plain.string(), "--frames", plain.string(), "--out", out.string()});
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_FALSE(fs::exists(out));
}

// Rotation metadata: a landscape clip stored with "rotate 90" is taken as the portrait it shows,
// the same pixels as the clip turned by ffmpeg itself and stored without metadata.
TEST(spar_footage, RotationMetadataIsHonoured) {
  const fs::path plain = makeClip("landscape.mp4");
  const fs::path rotated = scratch() / "rotated.mp4", turned = scratch() / "turned.mkv";
  ASSERT_EQ(runCommand({"ffmpeg", "-v", "error", "-y", "-i", plain.string(), "-c", "copy", "-metadata:s:v:0", "rotate=90",
                        rotated.string()}, scratch()).code, 0);
  ASSERT_EQ(runCommand({"ffmpeg", "-v", "error", "-y", "-i", rotated.string(), "-c:v", "ffv1", turned.string()}, scratch()).code,
            0);  // decoded with ffmpeg's rotation applied, stored upright (lossless)
  for (const fs::path& v : {rotated, turned}) {
    const fs::path out = scratch() / ("rot_" + v.stem().string());
    fs::remove_all(out);
    const CommandResult r = spar({"render", "--model", kModel.string(), "--video", v.string(), "--video-frames", "3",
                                  "--size", "96x64", "--out", out.string()});
    ASSERT_EQ(r.code, 0) << r.err;
  }
  // Both runs saw the same portrait frames: their motion maps and cameras agree.
  for (const char* f : {"motion_00.png", "motion_01.png"}) {
    const RgbImage a = loadImageRGB((scratch() / "rot_rotated" / f).string());
    const RgbImage b = loadImageRGB((scratch() / "rot_turned" / f).string());
    ASSERT_EQ(a.pixels.size(), b.pixels.size());
    size_t far = 0;
    for (size_t i = 0; i < a.pixels.size(); ++i) far += std::abs(int(a.pixels[i]) - int(b.pixels[i])) > 8;
    EXPECT_LT(double(far) / double(a.pixels.size()), 0.01) << f;
  }
}

}  // namespace
}  // namespace spar::test

namespace spar::test {
namespace {

// A jobs file (spar render --jobs, docs/many-scenes.md) takes a video the way --video does.
TEST(spar_footage, VideoJobInAJobsFile) {
  const fs::path clip = makeClip("job_clip.mp4"), jobs = scratch() / "jobs.jsonl", out = scratch() / "job_out";
  fs::remove_all(out);
  std::ofstream(jobs) << "{\"out\": \"" << out.string() << "\", \"video\": \"" << clip.string()
                      << "\", \"video_at\": [0.25, 0.75, 1.5], \"inputs\": [0, 2]}\n";
  const CommandResult r = spar({"render", "--model", kModel.string(), "--jobs", jobs.string()});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(fs::exists(out / "view_00.png"));
  expectValidCameras(out, 3);
  EXPECT_NE(readJson(out / "cameras.json")["frames"][1]["file_path"].get<std::string>().find("job_clip.mp4@0.750s"),
            std::string::npos);
}

}  // namespace
}  // namespace spar::test
