// path.gif of `spar render --path N`: the rendered camera path as an animated GIF, written
// with OpenImageIO's GIF writer (one subimage per frame), so no external tool is needed.
// Each frame shows the rendered view and, when labels were asked for, its label map beside it.
#pragma once
#include <string>
#include <vector>

#include "imaging/image_prep.h"

namespace spar::cli {

// Frames side by side on black: every part top-aligned, left to right.
RgbImage besideEachOther(const std::vector<const RgbImage*>& parts);

// Writes `frames` (all the same size) as a looping animation at `fps` frames a second.
// Throws spar::Error naming the file when OpenImageIO cannot write it.
void writeAnimatedGif(const std::string& path, const std::vector<RgbImage>& frames, int fps);

}  // namespace spar::cli
