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

// rgb [3, height, width] in [0, 1] (clamped) as an 8-bit PNG, rounded as the reference rounds.
SPAR_API void writePng(const std::string& path, const std::vector<float>& rgb, int height, int width);

}  // namespace spar
