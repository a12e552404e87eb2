#include "tools/spar/animation.h"

#include <filesystem>

#include "spar/error.h"
#include "tools/spar/ffmpeg_video.h"
#include "tools/spar/gif_animation.h"

namespace spar::cli {

AnimationChoice chooseAnimation(const std::string& video) {
  AnimationChoice c;
  if (video == "gif") {
    c.kind = "gif";
    return c;
  }
  c.ffmpeg = findFfmpeg();
  if (video == "mp4" && c.ffmpeg.empty())
    throw Error("--animation mp4 needs ffmpeg (Debian: apt-get install ffmpeg; or SPAR_FFMPEG=/path/to/ffmpeg)");
  if (video != "mp4" && video != "auto") throw Error("--animation must be auto, mp4 or gif, got '" + video + "'");
  c.kind = c.ffmpeg.empty() ? "gif" : "mp4";
  if (c.ffmpeg.empty()) c.note = "ffmpeg not found, so no path.mp4";
  return c;
}

std::unique_ptr<Animation> openAnimation(const AnimationChoice& c, const std::string& dir, int fps) {
  const std::filesystem::path d(dir);
  if (c.kind == "mp4") return std::make_unique<FfmpegVideo>(c.ffmpeg, (d / "path.mp4").string(), fps);
  return std::make_unique<GifAnimation>((d / "path.gif").string(), fps, c.note);
}

}  // namespace spar::cli
