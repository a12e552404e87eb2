// Image preparation of the reference (reference/spar_reference/images.py), on the CPU:
// load any common image format through OpenImageIO as 8-bit RGB, resize with a bit-exact
// reproduction of PIL's Image.resize(..., Image.LANCZOS) on 8-bit images, centre crop, /255 into
// a [3, H, W] float buffer; and PNG output with the reference's rounding rule.
// Every problem is a spar::Error with a one-line message naming the file.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

namespace spar {

// An 8-bit RGB image, rows top to bottom, pixels interleaved: pixels[(y * width + x) * 3 + c].
struct RgbImage {
  int width = 0, height = 0;
  std::vector<uint8_t> pixels;
};

// Largest image loadImageRGB reads, judged from the file's header before decoding (a damaged
// or hostile header may claim 2^31 rows): a side of 32768 pixels and 2^27 pixels (512 MB of
// 16-bit RGBA while decoding).
constexpr int kMaxImageSide = 32768;
constexpr int64_t kMaxImagePixels = int64_t(1) << 27;

// Loads an image (PNG, JPEG, TIFF, BMP, ... whatever OpenImageIO reads) as 8-bit RGB the way
// PIL's Image.open(path).convert("RGB") gives it for 8-bit files: grey is replicated, alpha is
// dropped (not composited; PNG alpha is read unassociated), turned as its EXIF orientation says
// (a phone photo held upright is upright here, as PIL's ImageOps.exif_transpose shows it).
// Other sample types: 16-bit integers keep their high byte (checked equal to PIL for 16-bit RGB
// PNGs; PIL opens 16-bit grey PNGs as mode "I" and clips them to 255, which is not reproduced:
// they keep the high byte too); floats are clamped to [0, 1] and rounded to 8 bits (OpenImageIO's
// conversion).
// Throws spar::Error for a missing file, an unreadable or unsupported image, a zero size.
RgbImage loadImageRGB(const std::string& path);
// The image as shown under EXIF orientation tag 1-8 (2: mirrored, 3: rotated 180, 6: stored
// rotated so it shows turned 90 degrees clockwise, ...); other values leave it as stored.
RgbImage applyOrientation(RgbImage image, int orientation);

// PIL's ImagingResample with the LANCZOS filter on an 8-bit image: separable, horizontal pass
// (only if the width changes) then vertical pass (only if the height changes), support 3 scaled
// by the downscale factor, coefficients normalized per output pixel and quantized to 22
// fractional bits, each pass rounded and clipped to 8 bits. Bit-exact with Pillow.
RgbImage resizeLanczos(const RgbImage& image, int newWidth, int newHeight);

// The reference's crop geometry: s = max(H / h, W / w), resized size nw = max(W, round(w * s)),
// nh = max(H, round(h * s)) (round half to even), crop origin ((nw - W) / 2, (nh - H) / 2).
struct CropGeometry {
  int resizedWidth = 0, resizedHeight = 0, left = 0, top = 0;
};
CropGeometry cropGeometry(int width, int height, int outWidth, int outHeight);

// The prepared model input: resize to cover outHeight x outWidth (no resize when the size is
// already right), centre crop, values / 255 as float, layout [3, outHeight, outWidth].
std::vector<float> prepareImage(const RgbImage& rgb, int outHeight, int outWidth);
// loadImageRGB + prepareImage.
std::vector<float> loadPreparedImage(const std::string& path, int outHeight, int outWidth);

// The reference's 8-bit rule: floor(clip(x, 0, 1) * 255 + 0.5) (NaN -> 0).
uint8_t toUint8(double x);

// Writes an 8-bit PNG through OpenImageIO: channels == 3: values are [3, height, width] (CHW)
// RGB; channels == 1: values are [height, width] grey. Samples use toUint8. The file is written
// under a temporary name in the same directory and renamed, so `path` is never half-written.
void writePng(const std::string& path, const float* values, int channels, int height, int width);
void writePng(const std::string& path, const std::vector<float>& values, int channels, int height, int width);
// An 8-bit RGB image as it is.
void writePng(const std::string& path, const RgbImage& image);

}  // namespace spar
