// The animation of `spar render --path N`: the rendered views (beside their label maps) as
// path.mp4 (H.264 through Debian's ffmpeg, when it is installed) or path.gif (OpenImageIO's GIF
// writer, always available). Frames are written as they are rendered, so a long path holds one
// frame in memory, not all of them.
#pragma once
#include <memory>
#include <string>

#include "imaging/image_prep.h"

namespace spar::cli {

class Animation {
 public:
  virtual ~Animation() = default;
  // Appends one frame; every frame has the first one's size. Throws spar::Error naming the file.
  virtual void add(const RgbImage& frame) = 0;
  // Completes the file; throws spar::Error (with the encoder's own message) if it failed.
  virtual void finish() = 0;
  // The file's name inside the output directory and how it was written, for the user.
  virtual std::string fileName() const = 0;
  virtual std::string description() const = 0;
};

// --animation: "mp4", "gif", or "auto" (mp4 when ffmpeg is found, else gif).
struct AnimationChoice {
  std::string kind;     // "mp4" or "gif"
  std::string ffmpeg;   // the ffmpeg executable, for mp4
  std::string note;     // why auto chose gif ("" otherwise)
};

// Resolves --animation before any work: "mp4" without an ffmpeg is an error (spar::Error).
// SPAR_FFMPEG names the executable (default: `ffmpeg` on PATH); "" or a missing file: none.
AnimationChoice chooseAnimation(const std::string& video);

// Starts writing the animation into `dir` at `fps` frames a second.
std::unique_ptr<Animation> openAnimation(const AnimationChoice& choice, const std::string& dir, int fps);

}  // namespace spar::cli
