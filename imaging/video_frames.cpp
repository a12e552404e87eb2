#include "imaging/video_frames.h"

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <regex>

#include "spar/error.h"
#include "imaging/child_process.h"

namespace spar {
namespace {

constexpr int kProbeTimeoutMs = 60000, kFrameTimeoutMs = 120000;

std::string seconds(double t) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3f", t);
  return buf;
}

// ffmpeg's complaint without its "[mov,mp4,... @ 0x55...] " prefixes (an address is noise).
std::string complaint(const std::string& stderrText) {
  static const std::regex prefix(R"(\[[^\]]* @ 0x[0-9a-fA-F]+\] ?)");
  return std::regex_replace(lastLines(stderrText), prefix, "");
}

double number(const nlohmann::json& j, const char* key) {
  if (!j.contains(key)) return 0;
  const auto& v = j.at(key);
  if (v.is_number()) return v.get<double>();
  if (v.is_string()) {
    try {
      return std::stod(v.get<std::string>());
    } catch (const std::exception&) {
      return 0;
    }
  }
  return 0;
}

}  // namespace

VideoInfo probeVideo(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) throw Error("video not found: " + path);
  if (std::filesystem::is_directory(path, ec)) throw Error("cannot read video " + path + ": it is a directory");
  const std::string ffprobe = findFfprobe();
  if (ffprobe.empty())
    throw Error("reading video " + path + " needs ffprobe (Debian: apt-get install ffmpeg; or SPAR_FFMPEG=/path/to/ffmpeg)");
  const ProcessOutput p = runProcess({ffprobe, "-v", "error", "-select_streams", "v:0", "-show_entries",
                                      "stream=width,height,nb_frames,duration:stream_side_data=rotation:format=duration",
                                      "-of", "json", path},
                                     1 << 20, kProbeTimeoutMs);
  const std::string why = complaint(p.err);
  if (p.exitCode != 0)
    throw Error("cannot read video " + path + ": " + (p.timedOut ? "ffprobe took too long" : why.empty() ? "ffprobe failed" : why));
  nlohmann::json doc;
  try {
    doc = nlohmann::json::parse(p.out);
  } catch (const std::exception&) {
    throw Error("cannot read video " + path + ": ffprobe's answer is not JSON");
  }
  if (!doc.contains("streams") || !doc["streams"].is_array() || doc["streams"].empty())
    throw Error("cannot read video " + path + ": no video stream (audio only, or not a video)");
  const nlohmann::json& s = doc["streams"][0];
  VideoInfo info;
  const int w = int(number(s, "width")), h = int(number(s, "height"));
  if (w < 1 || h < 1) throw Error("cannot read video " + path + ": its video stream has no size");
  if (s.contains("side_data_list") && s["side_data_list"].is_array())
    for (const auto& d : s["side_data_list"])
      if (d.contains("rotation")) info.rotation = int(number(d, "rotation"));
  const bool turned = std::abs(info.rotation) % 180 == 90;
  info.width = turned ? h : w;
  info.height = turned ? w : h;
  info.duration = number(s, "duration");
  if (!(info.duration > 0) && doc.contains("format")) info.duration = number(doc["format"], "duration");
  const double frames = number(s, "nb_frames");
  if (s.contains("nb_frames") && frames == 0) throw Error("cannot read video " + path + ": it has no frames");
  if (!(info.duration > 0) || !std::isfinite(info.duration))
    throw Error("cannot read video " + path + ": no duration (no frames, or a damaged file)");
  return info;
}

std::vector<double> spreadTimes(const VideoInfo& info, int count) {
  if (count < 1) throw Error("a video needs at least 1 frame to take, got " + std::to_string(count));
  std::vector<double> t;
  for (int i = 0; i < count; ++i) t.push_back(info.duration * (i + 0.5) / count);
  return t;
}

std::vector<RgbImage> readVideoFrames(const std::string& path, const VideoInfo& info, const std::vector<double>& times,
                                      int height, int width) {
  const std::string ffmpeg = findFfmpeg();
  if (ffmpeg.empty())
    throw Error("reading video " + path + " needs ffmpeg (Debian: apt-get install ffmpeg; or SPAR_FFMPEG=/path/to/ffmpeg)");
  const size_t bytes = size_t(width) * size_t(height) * 3;
  // Cover the model size keeping the aspect, then the centre: the image preparation's geometry,
  // done by ffmpeg (after its automatic rotation) before the frame reaches this process.
  const std::string filter = "scale=" + std::to_string(width) + ":" + std::to_string(height) +
                             ":force_original_aspect_ratio=increase:flags=lanczos,crop=" + std::to_string(width) + ":" +
                             std::to_string(height);
  std::vector<RgbImage> frames;
  for (double t : times) {
    if (!(t >= 0) || !(t < info.duration))
      throw Error("video " + path + " is " + seconds(info.duration) + " s long: no frame at " + seconds(t) + " s");
    const ProcessOutput p = runProcess({ffmpeg, "-hide_banner", "-nostdin", "-v", "error", "-ss", seconds(t), "-i", path,
                                        "-map", "0:v:0", "-frames:v", "1", "-vf", filter, "-pix_fmt", "rgb24", "-f",
                                        "rawvideo", "pipe:1"},
                                       bytes, kFrameTimeoutMs);
    if (p.exitCode != 0 || p.out.size() != bytes) {
      const std::string why = complaint(p.err);
      throw Error("cannot read video " + path + ": no frame at " + seconds(t) + " s" +
                  (p.timedOut ? " (ffmpeg took too long)" : why.empty() ? "" : " (" + why + ")"));
    }
    RgbImage f;
    f.width = width;
    f.height = height;
    f.pixels.assign(p.out.begin(), p.out.end());
    frames.push_back(std::move(f));
  }
  return frames;
}

}  // namespace spar
