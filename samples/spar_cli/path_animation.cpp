#include "samples/spar_cli/path_animation.h"

#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <cstring>

#include "engine/error.h"

namespace spar::cli {

RgbImage besideEachOther(const std::vector<const RgbImage*>& parts) {
  RgbImage out;
  for (const RgbImage* p : parts) {
    out.width += p->width;
    out.height = std::max(out.height, p->height);
  }
  out.pixels.assign(size_t(out.width) * out.height * 3, 0);
  int x0 = 0;
  for (const RgbImage* p : parts) {
    for (int y = 0; y < p->height; ++y)
      std::memcpy(&out.pixels[(size_t(y) * out.width + x0) * 3], &p->pixels[size_t(y) * p->width * 3],
                  size_t(p->width) * 3);
    x0 += p->width;
  }
  return out;
}

void writeAnimatedGif(const std::string& path, const std::vector<RgbImage>& frames, int fps) {
  if (frames.empty()) throw Error("no frames to animate in " + path);
  auto out = OIIO::ImageOutput::create(path);
  if (!out) throw Error("cannot write " + path + ": " + OIIO::geterror());
  if (!out->supports("multiimage") || !out->supports("appendsubimage"))
    throw Error("cannot write " + path + ": this OpenImageIO writes no animated GIF");
  OIIO::ImageSpec spec(frames[0].width, frames[0].height, 3, OIIO::TypeDesc::UINT8);
  const int rate[2] = {fps, 1};
  spec.attribute("FramesPerSecond", OIIO::TypeRational, rate);
  spec.attribute("oiio:Movie", 1);
  spec.attribute("oiio:LoopCount", 0);  // loop forever
  for (size_t i = 0; i < frames.size(); ++i) {
    const RgbImage& f = frames[i];
    if (f.width != spec.width || f.height != spec.height) throw Error("animation frames differ in size: " + path);
    const auto mode = i == 0 ? OIIO::ImageOutput::Create : OIIO::ImageOutput::AppendSubimage;
    if (!out->open(path, spec, mode) || !out->write_image(OIIO::TypeDesc::UINT8, f.pixels.data()))
      throw Error("cannot write " + path + ": " + out->geterror());
  }
  if (!out->close()) throw Error("cannot write " + path + ": " + out->geterror());
}

}  // namespace spar::cli
