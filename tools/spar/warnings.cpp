#include "tools/spar/warnings.h"

#include <cstdio>


namespace spar::cli {

namespace {
std::vector<std::string>& printed() {
  static std::vector<std::string> lines;
  return lines;
}
}  // namespace

void warn(const std::string& message) {
  std::string line = message;
  for (char& c : line)
    if (c == '\n' || c == '\r') c = ' ';
  std::fprintf(stderr, "spar: warning: %s\n", line.c_str());
  printed().push_back(line);
}

std::vector<std::string> takeWarnings() {
  std::vector<std::string> out;
  out.swap(printed());
  return out;
}

void warnIfTiny(const std::string& file, int width, int height, int modelWidth, int modelHeight) {
  if (width * 4 < modelWidth || height * 4 < modelHeight)
    warn(file + " is " + std::to_string(width) + "x" + std::to_string(height) + " pixels, far smaller than the " +
         std::to_string(modelWidth) + "x" + std::to_string(modelHeight) + " the model runs at: it is upscaled");
}

void warnIfManyViews(int64_t trained, size_t views, size_t inputs) {
  if (trained > 0 && int64_t(views) > trained)
    warn(std::to_string(views) + " views (" + std::to_string(inputs) + " inputs): the model was trained with " +
         std::to_string(trained) + " views a scene; results far outside that are untested");
}

void warnAboutPrompts(const std::vector<std::string>& promptWarnings, size_t count) {
  for (const std::string& w : promptWarnings) warn(w);
  if (count > 20)
    warn(std::to_string(count) + " labels: the palette has 20 well-separated colours; labels 21 and on "
         "get colours of their own, which may look alike");
}

}  // namespace spar::cli
