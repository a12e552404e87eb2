#include "imaging/float_image.h"

#include <vector>

#include "spar/error.h"
#include "imaging/image_files.h"
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
  const ImageFiles& files = imageFiles();  // loaded before stderr is captured: its errors are one line
  StderrCapture captured;
  std::string error;
  const std::vector<std::string> names = channels == 3 ? std::vector<std::string>{"R", "G", "B"} : std::vector<std::string>{"Y"};
  if (!files.writeFloats(path, width, height, channels, half, interleaved.data(), names, "zip", &error))
    throw Error("cannot write " + path + ": " + error + " " + captured.take());
}

}  // namespace spar
