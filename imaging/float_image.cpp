#include "imaging/float_image.h"

#include <OpenImageIO/imageio.h>

#include <vector>

#include "engine/error.h"
#include "imaging/stderr_capture.h"

namespace spar {

void writeExr(const std::string& path, const float* values, int channels, int height, int width, bool half) {
  if ((channels != 1 && channels != 3) || height <= 0 || width <= 0)
    throw Error("writeExr " + path + ": " + std::to_string(channels) + " channels of " + std::to_string(height) + "x" +
                std::to_string(width));
  const size_t plane = size_t(height) * size_t(width);
  std::vector<float> interleaved(plane * size_t(channels));  // EXR scanlines hold pixels, not planes
  for (int c = 0; c < channels; ++c)
    for (size_t i = 0; i < plane; ++i) interleaved[i * size_t(channels) + size_t(c)] = values[size_t(c) * plane + i];
  StderrCapture captured;
  auto out = OIIO::ImageOutput::create(path);
  if (!out) throw Error("cannot write " + path + ": " + OIIO::geterror() + " " + captured.take());
  OIIO::ImageSpec spec(width, height, channels, half ? OIIO::TypeDesc::HALF : OIIO::TypeDesc::FLOAT);
  spec.channelnames = channels == 3 ? std::vector<std::string>{"R", "G", "B"} : std::vector<std::string>{"Y"};
  spec.attribute("compression", "zip");
  if (!out->open(path, spec) || !out->write_image(OIIO::TypeDesc::FLOAT, interleaved.data()) || !out->close())
    throw Error("cannot write " + path + ": " + out->geterror() + " " + captured.take());
}

}  // namespace spar
