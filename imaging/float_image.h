// Float image files for outputs that must not go through 8 bits (spar render --format exr /
// exr16): OpenEXR through OpenImageIO, RGB channels, float32 or half (fp16, rounded to
// nearest even by OpenImageIO).
#pragma once
#include <string>

namespace spar {

// values [channels, height, width] (channels 1 or 3: Y or R, G, B), written as given (no clamp).
// Throws spar::Error naming the file.
void writeExr(const std::string& path, const float* values, int channels, int height, int width, bool half);

}  // namespace spar
