// Frames of a video file (any container and codec ffmpeg reads, any size and frame rate,
// variable too), decoded by Debian's ffmpeg in a child process: turned as the file's rotation
// metadata says, cover-resized (Lanczos) and centre-cropped to the model's size by ffmpeg, so
// a frame is at the model's size before it is held in memory. `spar render --video`, the public
// spar::loadVideoFrames and `spar.load_video` use it.
#pragma once
#include <string>
#include <vector>

#include "imaging/image_prep.h"

namespace spar {

struct VideoInfo {
  double duration = 0;       // seconds
  int width = 0, height = 0;  // as shown (after the rotation metadata)
  int rotation = 0;          // degrees, as the file says
};

// Throws spar::Error, one line naming the file: not found, not a video ffprobe reads (corrupt,
// truncated), no video stream (audio only), no duration or no frames, no ffprobe installed.
VideoInfo probeVideo(const std::string& path);

// `count` times spread evenly over the clip: the middles of `count` equal parts.
std::vector<double> spreadTimes(const VideoInfo& info, int count);

// The frames shown at `times` (seconds, each in [0, duration)), each width x height 8-bit RGB.
// Throws spar::Error naming the file and time for a time outside the clip or a frame ffmpeg
// cannot decode there.
std::vector<RgbImage> readVideoFrames(const std::string& path, const VideoInfo& info, const std::vector<double>& times,
                                      int height, int width);

}  // namespace spar
