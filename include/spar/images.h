// Image files for requests and results (OpenImageIO inside the library, not in its interface).
#pragma once
#include <string>
#include <vector>

#include "spar/export.h"

namespace spar {

// An image file (PNG, JPEG, EXR, ... anything OpenImageIO reads) prepared as SPAR's reference
// does: 8-bit RGB, resized to cover height x width with PIL's Lanczos filter, centre-cropped,
// divided by 255. Returns [3, height, width]. Throws spar::Error naming the file.
SPAR_API std::vector<float> loadImage(const std::string& path, int height, int width);

// Frames of a video file (anything ffmpeg reads; Debian's ffmpeg package must be installed),
// as `spar render --video` takes them: `count` frames spread evenly over the clip (the middles
// of `count` equal parts), or the frames shown at the seconds in `at` when it is not empty;
// each turned as the file's rotation metadata says, cover-resized and centre-cropped to height x
// width by ffmpeg. Returns [N, 3, height, width] in [0, 1]; the times taken go to *times. Throws
// spar::Error (one line naming the file: missing, corrupt, truncated, audio only, no frames,
// a time outside the clip, no ffmpeg).
SPAR_API std::vector<float> loadVideoFrames(const std::string& path, int height, int width, int count,
                                            const std::vector<double>& at = {}, std::vector<double>* times = nullptr);
// rgb [3, height, width] in [0, 1] (clamped) as an 8-bit PNG, rounded as the reference rounds.
SPAR_API void writePng(const std::string& path, const std::vector<float>& rgb, int height, int width);

}  // namespace spar
