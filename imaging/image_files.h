// Image files (read, write, text, animated GIF) through OpenImageIO, in a module of their own
// (spar_image_files.so) loaded on first use. OpenImageIO links about 250 libraries, whose loading
// costs a process 0.35-0.4 s before main on this machine's two cores: a process that touches no
// image file (spar --help, a refused command line, an op test, a library user whose tensors are
// in memory) never pays it. The callers keep their own checks and error wording: these calls
// only report OpenImageIO's result, false with its message in *error.
#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace spar {

// An opened image file, its header read and no pixel decoded yet.
class ImageFileReader {
 public:
  virtual ~ImageFileReader() = default;
  int width = 0, height = 0, depth = 1, channels = 0;
  bool sixteenBit = false;  // stored as 16-bit integers: read() gives uint16 values, else uint8
  int orientation = 1;      // the EXIF orientation tag (1: as stored)
  // All channels of all pixels, interleaved, as uint16 or uint8 (sixteenBit).
  virtual bool read(void* pixels, std::string* error) = 0;
};

// An animation written frame by frame (GIF: one subimage per frame).
class AnimationFileWriter {
 public:
  virtual ~AnimationFileWriter() = default;
  virtual bool add(const uint8_t* rgb, std::string* error) = 0;  // width x height x 3
  virtual bool close(std::string* error) = 0;
};

class ImageFiles {
 public:
  virtual ~ImageFiles() = default;
  // PNG/TIFF alpha as stored (unassociated): nullptr and *error when the file cannot be opened.
  virtual std::unique_ptr<ImageFileReader> open(const std::string& path, std::string* error) const = 0;
  // Writes width x height x channels interleaved floats to path, in the format its extension
  // names, stored as half or float, with these channel names and compression attribute.
  virtual bool writeFloats(const std::string& path, int width, int height, int channels, bool half,
                           const float* values, const std::vector<std::string>& channelNames,
                           const std::string& compression, std::string* error) const = 0;
  // Draws text in white on an RGB uint8 image, its baseline starting at (x, y), with a font file.
  virtual bool drawText(uint8_t* rgb, int width, int height, int x, int y, const std::string& text, int fontSize,
                        const std::string& fontFile, std::string* error) const = 0;
  // A looping animated GIF of width x height frames at fps.
  virtual std::unique_ptr<AnimationFileWriter> openAnimation(const std::string& path, int width, int height, int fps,
                                                             std::string* error) const = 0;
};

// The module, loaded once; throws spar::Error (one line: where it looked, dlerror) when absent.
const ImageFiles& imageFiles();

}  // namespace spar

// What the module exports (the version is in the name: a stale module is refused, not misread).
extern "C" const spar::ImageFiles* spar_image_files_v1();
