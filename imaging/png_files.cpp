#include "imaging/png_files.h"

#include <png.h>

#include <cerrno>
#include <csetjmp>
#include <cstdio>
#include <cstring>
#include <vector>

namespace spar {
namespace {

// libpng reports errors by longjmp to the setjmp of the call that failed; each method below
// arms its own, and no object with a destructor is created between setjmp and the libpng calls.
void onError(png_structp png, png_const_charp message) {
  *static_cast<std::string*>(png_get_error_ptr(png)) = message ? message : "unknown error";
  std::longjmp(png_jmpbuf(png), 1);
}
void onWarning(png_structp, png_const_charp) {}  // libpng's warnings are not errors of ours

class PngReader : public ImageFileReader {
 public:
  ~PngReader() override {
    if (png_) png_destroy_read_struct(&png_, info_ ? &info_ : nullptr, nullptr);
    if (file_) std::fclose(file_);
  }

  // The header and the transforms to OpenImageIO's pixels; false with the message in message_.
  bool open(const std::string& path, bool* notMine) {
    file_ = std::fopen(path.c_str(), "rb");
    if (!file_) return fail(std::strerror(errno));
    png_byte signature[8] = {};
    if (std::fread(signature, 1, sizeof signature, file_) != sizeof signature || png_sig_cmp(signature, 0, 8)) {
      *notMine = true;
      return false;
    }
    png_ = png_create_read_struct(PNG_LIBPNG_VER_STRING, &message_, onError, onWarning);
    if (!png_) return fail("out of memory");
    info_ = png_create_info_struct(png_);
    if (!info_) return fail("out of memory");
    if (setjmp(png_jmpbuf(png_))) return fail("PNG read error: " + message_);
    png_init_io(png_, file_);
    png_set_sig_bytes(png_, 8);
    png_read_info(png_, info_);
    png_uint_32 exifSize = 0;
    png_bytep exifData = nullptr;
    *notMine = png_get_eXIf_1(png_, info_, &exifSize, &exifData) != 0;
    const int colour = png_get_color_type(png_, info_), bits = png_get_bit_depth(png_, info_);
    if (colour == PNG_COLOR_TYPE_PALETTE) png_set_palette_to_rgb(png_);
    if (colour == PNG_COLOR_TYPE_GRAY && bits < 8) png_set_expand_gray_1_2_4_to_8(png_);
    if (png_get_valid(png_, info_, PNG_INFO_tRNS)) png_set_tRNS_to_alpha(png_);
    const uint16_t one = 1;
    if (bits == 16 && *reinterpret_cast<const uint8_t*>(&one) == 1) png_set_swap(png_);  // libpng gives big-endian
    png_set_interlace_handling(png_);
    png_read_update_info(png_, info_);
    width = int(png_get_image_width(png_, info_));
    height = int(png_get_image_height(png_, info_));
    channels = png_get_channels(png_, info_);
    sixteenBit = png_get_bit_depth(png_, info_) == 16;
    return true;
  }

  bool read(void* pixels, std::string* error) override {
    const size_t rowBytes = size_t(width) * size_t(channels) * (sixteenBit ? 2 : 1);
    rows_.resize(size_t(height));
    for (size_t y = 0; y < rows_.size(); ++y) rows_[y] = static_cast<png_bytep>(pixels) + y * rowBytes;
    if (setjmp(png_jmpbuf(png_))) {
      *error = "PNG read error: " + message_;
      return false;
    }
    png_read_image(png_, rows_.data());
    png_read_end(png_, nullptr);
    return true;
  }

  std::string message_;

 private:
  bool fail(const std::string& message) {
    message_ = message;
    return false;
  }
  std::FILE* file_ = nullptr;
  png_structp png_ = nullptr;
  png_infop info_ = nullptr;
  std::vector<png_bytep> rows_;
};

struct PngWriter {
  std::FILE* file = nullptr;
  png_structp png = nullptr;
  png_infop info = nullptr;
  std::string message;
  ~PngWriter() {
    if (png) png_destroy_write_struct(&png, info ? &info : nullptr);
    if (file) std::fclose(file);
  }
};

}  // namespace

std::unique_ptr<ImageFileReader> openPng(const std::string& path, bool* notMine, std::string* error) {
  *notMine = false;
  auto reader = std::make_unique<PngReader>();
  const bool opened = reader->open(path, notMine);
  if (*notMine) return nullptr;
  if (!opened) {
    *error = reader->message_;
    return nullptr;
  }
  return reader;
}

bool writePng8(const std::string& path, const uint8_t* data, int channels, int height, int width, std::string* error) {
  static const int kColour[5] = {-1, PNG_COLOR_TYPE_GRAY, PNG_COLOR_TYPE_GRAY_ALPHA, PNG_COLOR_TYPE_RGB,
                                 PNG_COLOR_TYPE_RGB_ALPHA};
  if (channels < 1 || channels > 4 || width < 1 || height < 1) {
    *error = std::to_string(channels) + " channels of " + std::to_string(width) + "x" + std::to_string(height);
    return false;
  }
  PngWriter w;
  std::vector<png_bytep> rows(static_cast<size_t>(height));
  for (size_t y = 0; y < rows.size(); ++y)
    rows[y] = const_cast<png_bytep>(data) + y * size_t(width) * size_t(channels);
  w.file = std::fopen(path.c_str(), "wb");
  if (!w.file) {
    *error = std::strerror(errno);
    return false;
  }
  w.png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &w.message, onError, onWarning);
  if (w.png) w.info = png_create_info_struct(w.png);
  if (!w.png || !w.info) {
    *error = "out of memory";
    return false;
  }
  if (setjmp(png_jmpbuf(w.png))) {
    *error = "PNG write error: " + w.message;
    return false;
  }
  png_init_io(w.png, w.file);
  png_set_IHDR(w.png, w.info, png_uint_32(width), png_uint_32(height), 8, kColour[channels], PNG_INTERLACE_NONE,
               PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_write_info(w.png, w.info);
  png_write_image(w.png, rows.data());
  png_write_end(w.png, nullptr);
  if (std::fflush(w.file) != 0 || std::ferror(w.file)) {
    *error = std::strerror(errno);
    return false;
  }
  return true;
}

}  // namespace spar
