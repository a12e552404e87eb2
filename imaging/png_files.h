// PNG, the format of every file spar writes and of most it reads, through libpng directly (two
// small libraries): a process that reads and writes only PNGs never loads OpenImageIO and its
// ~250 libraries (image_files.h), which cost it 0.35-0.4 s before any work on this machine.
// Pixels are as OpenImageIO gives them: values as stored, palettes and grey of 1-4 bits
// expanded to 8 bits, 16-bit samples kept (callers take the high byte), no gamma applied.
#pragma once
#include <cstdint>
#include <memory>
#include <string>

#include "imaging/image_files.h"

namespace spar {

// A PNG file's reader, its header read. nullptr and *notMine when the file is no PNG or has an
// eXIf chunk (OpenImageIO reads those: it applies their orientation); nullptr and *error when it
// is a PNG that cannot be read.
std::unique_ptr<ImageFileReader> openPng(const std::string& path, bool* notMine, std::string* error);

// 8-bit grey (1), grey+alpha (2), RGB (3) or RGBA (4), interleaved rows top to bottom.
bool writePng8(const std::string& path, const uint8_t* data, int channels, int height, int width, std::string* error);

}  // namespace spar
