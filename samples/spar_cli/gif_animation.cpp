#include "samples/spar_cli/gif_animation.h"

#include "engine/error.h"

namespace spar::cli {

GifAnimation::GifAnimation(const std::string& path, int fps, std::string note)
    : path_(path), note_(std::move(note)), fps_(fps) {}

GifAnimation::~GifAnimation() {
  if (out_) out_->close();  // an unfinished file is removed with the staged directory
}

std::string GifAnimation::description() const { return "GIF" + (note_.empty() ? "" : " (" + note_ + ")"); }

void GifAnimation::add(const RgbImage& f) {
  if (!out_) {
    out_ = OIIO::ImageOutput::create(path_);
    if (!out_) throw Error("cannot write " + path_ + ": " + OIIO::geterror());
    if (!out_->supports("multiimage") || !out_->supports("appendsubimage"))
      throw Error("cannot write " + path_ + ": this OpenImageIO writes no animated GIF");
    spec_ = OIIO::ImageSpec(f.width, f.height, 3, OIIO::TypeDesc::UINT8);
    const int rate[2] = {fps_, 1};
    spec_.attribute("FramesPerSecond", OIIO::TypeRational, rate);
    spec_.attribute("oiio:Movie", 1);
    spec_.attribute("oiio:LoopCount", 0);  // loop forever
    if (!out_->open(path_, spec_, OIIO::ImageOutput::Create))
      throw Error("cannot write " + path_ + ": " + out_->geterror());
  } else {
    if (f.width != spec_.width || f.height != spec_.height) throw Error("animation frames differ in size: " + path_);
    if (!out_->open(path_, spec_, OIIO::ImageOutput::AppendSubimage))
      throw Error("cannot write " + path_ + ": " + out_->geterror());
  }
  if (!out_->write_image(OIIO::TypeDesc::UINT8, f.pixels.data()))
    throw Error("cannot write " + path_ + ": " + out_->geterror());
}

void GifAnimation::finish() {
  if (!out_) throw Error("no frames to animate in " + path_);
  const bool ok = out_->close();
  const std::string err = ok ? "" : out_->geterror();
  out_.reset();
  if (!ok) throw Error("cannot write " + path_ + ": " + err);
}

}  // namespace spar::cli
