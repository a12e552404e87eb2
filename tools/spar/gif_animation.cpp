#include "tools/spar/gif_animation.h"

#include "spar/error.h"

namespace spar::cli {

GifAnimation::GifAnimation(const std::string& path, int fps, std::string note)
    : path_(path), note_(std::move(note)), fps_(fps) {}

GifAnimation::~GifAnimation() = default;  // an unfinished file is removed with the staged directory

std::string GifAnimation::description() const { return "GIF" + (note_.empty() ? "" : " (" + note_ + ")"); }

void GifAnimation::add(const RgbImage& f) {
  std::string error;
  if (!out_) {
    out_ = imageFiles().openAnimation(path_, f.width, f.height, fps_, &error);
    if (!out_) throw Error("cannot write " + path_ + ": " + error);
    width_ = f.width;
    height_ = f.height;
  } else if (f.width != width_ || f.height != height_) {
    throw Error("animation frames differ in size: " + path_);
  }
  if (!out_->add(f.pixels.data(), &error)) throw Error("cannot write " + path_ + ": " + error);
}

void GifAnimation::finish() {
  if (!out_) throw Error("no frames to animate in " + path_);
  std::string error;
  const bool ok = out_->close(&error);
  out_.reset();
  if (!ok) throw Error("cannot write " + path_ + ": " + error);
}

}  // namespace spar::cli
