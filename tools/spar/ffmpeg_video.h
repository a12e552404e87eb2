// path.mp4: frames piped as raw RGB into an ffmpeg child process that encodes H.264
// (yuv420p, so every player shows it; odd sizes padded by one black row or column, which
// yuv420p needs). ffmpeg's own messages go to a log file and are folded into the one-line error
// when it fails, instead of reaching the terminal.
#pragma once
#include <sys/types.h>

#include <string>

#include "imaging/child_process.h"
#include "tools/spar/animation.h"

namespace spar::cli {

// Where ffmpeg is: spar::findFfmpeg (imaging/child_process.h: SPAR_FFMPEG, else PATH).
using spar::findFfmpeg;

class FfmpegVideo : public Animation {
 public:
  FfmpegVideo(const std::string& ffmpeg, const std::string& path, int fps);
  ~FfmpegVideo() override;  // kills and reaps the child if finish() was not reached
  void add(const RgbImage& frame) override;
  void finish() override;
  std::string fileName() const override { return "path.mp4"; }
  std::string description() const override { return "H.264 MP4 through " + ffmpeg_; }

 private:
  void start(int width, int height);
  std::string failure(const std::string& what);  // the message, with ffmpeg's log appended

  std::string ffmpeg_, path_, log_;
  int fps_ = 0, width_ = 0, height_ = 0;
  int stdin_ = -1;
  pid_t child_ = -1;
};

}  // namespace spar::cli
