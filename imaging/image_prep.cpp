#include "imaging/image_prep.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <system_error>

#include "spar/error.h"
#include "imaging/image_files.h"
#include "imaging/png_files.h"
#include "imaging/stderr_capture.h"

namespace spar {
namespace {

namespace fs = std::filesystem;

// OpenImageIO messages can span lines; spar::Error messages are one line.
std::string oneLine(std::string s) {
  for (char& c : s)
    if (c == '\n' || c == '\r') c = ' ';
  while (!s.empty() && s.back() == ' ') s.pop_back();
  return s.empty() ? std::string("unknown error") : s;
}

// ---- PIL's resampling (src/libImaging/Resample.c), written from its documented behaviour ----

constexpr int kPrecisionBits = 32 - 8 - 2;  // fixed-point fraction bits of the 8-bit passes
constexpr double kLanczosSupport = 3.0;

double sinc(double x) {
  if (x == 0.0) return 1.0;
  x = x * M_PI;
  return std::sin(x) / x;
}

double lanczos(double x) {
  if (-3.0 <= x && x < 3.0) return sinc(x) * sinc(x / 3);
  return 0.0;
}

// Per output pixel: first input index, number of inputs, and the fixed-point weights (ksize
// slots each). The double arithmetic follows Pillow operation by operation, so the weights and
// their quantization are bit-identical.
struct Coeffs {
  int ksize = 0;
  std::vector<int> first, count;
  std::vector<int32_t> weights;
};

Coeffs precompute(int inSize, int outSize) {
  const float in0 = 0.0f, in1 = static_cast<float>(inSize);
  double scale = static_cast<double>(in1 - in0) / outSize;
  const double filterscale = scale < 1.0 ? 1.0 : scale;
  const double support = kLanczosSupport * filterscale;
  Coeffs c;
  c.ksize = static_cast<int>(std::ceil(support)) * 2 + 1;
  c.first.resize(outSize);
  c.count.resize(outSize);
  c.weights.assign(size_t(outSize) * c.ksize, 0);
  std::vector<double> k(c.ksize);
  for (int xx = 0; xx < outSize; ++xx) {
    const double center = in0 + (xx + 0.5) * scale;
    const double ss = 1.0 / filterscale;
    int xmin = static_cast<int>(center - support + 0.5);
    if (xmin < 0) xmin = 0;
    int xmax = static_cast<int>(center + support + 0.5);
    if (xmax > inSize) xmax = inSize;
    xmax -= xmin;
    double ww = 0.0;
    for (int x = 0; x < xmax; ++x) {
      const double w = lanczos((x + xmin - center + 0.5) * ss);
      k[x] = w;
      ww += w;
    }
    for (int x = 0; x < xmax; ++x)
      if (ww != 0.0) k[x] /= ww;
    for (int x = 0; x < xmax; ++x) {
      const double v = k[x] * (1 << kPrecisionBits);
      c.weights[size_t(xx) * c.ksize + x] = static_cast<int32_t>(k[x] < 0 ? -0.5 + v : 0.5 + v);
    }
    c.first[xx] = xmin;
    c.count[xx] = xmax;
  }
  return c;
}

// Rounded (the accumulator starts at one half) and clipped to 8 bits.
inline uint8_t clip8(int32_t acc) {
  const int32_t v = acc >> kPrecisionBits;  // arithmetic shift, as Pillow's lookup index
  return static_cast<uint8_t>(v < 0 ? 0 : v > 255 ? 255 : v);
}

}  // namespace

RgbImage loadImageRGB(const std::string& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error("image not found: " + path);
  if (fs::is_directory(path, ec)) throw Error("cannot read image " + path + ": it is a directory");

  // libpng and other codecs print their own complaints on stderr: they become part of the
  // one-line error (or are dropped when the read succeeds).
  StderrCapture captured;
  auto fail = [&](const std::string& what) -> Error {
    std::string printed = captured.take();
    return Error("cannot read image " + path + ": " + what + (printed.empty() ? "" : " (" + printed + ")"));
  };
  // PNG through libpng (png_files.h); other formats, and PNGs with EXIF data, through OpenImageIO.
  std::string error;
  bool notPng = false;
  std::unique_ptr<ImageFileReader> in = openPng(path, &notPng, &error);
  if (notPng) {
    try {
      in = imageFiles().open(path, &error);
    } catch (const Error& e) {  // the module is missing: say which file needed it
      throw fail(e.what());
    }
  }
  if (!in) throw fail(oneLine(error));
  const int w = in->width, h = in->height, nch = in->channels;
  if (w < 1 || h < 1 || in->depth > 1) throw Error("empty image: " + path);
  if (nch < 1) throw fail("no channels");
  // From the header, before any pixel is decoded: a header may claim any size.
  if (w > kMaxImageSide || h > kMaxImageSide || int64_t(w) * h > kMaxImagePixels || nch > 64)
    throw fail(std::to_string(w) + "x" + std::to_string(h) + " pixels, " + std::to_string(nch) +
               " channels: larger than this tool reads (" + std::to_string(kMaxImageSide) + " per side, " +
               std::to_string(kMaxImagePixels / 1000000) + " M pixels)");
  const size_t n = size_t(w) * h;

  // Source channels of R, G, B: grey (+ alpha) replicates channel 0; RGB(A...) takes 0, 1, 2.
  const int src[3] = {0, nch >= 3 ? 1 : 0, nch >= 3 ? 2 : 0};
  RgbImage out;
  out.width = w;
  out.height = h;
  out.pixels.resize(n * 3);
  if (in->sixteenBit) {
    std::vector<uint16_t> buf(n * nch);
    if (!in->read(buf.data(), &error)) throw fail(oneLine(error));
    for (size_t i = 0; i < n; ++i)
      for (int c = 0; c < 3; ++c) out.pixels[i * 3 + c] = static_cast<uint8_t>(buf[i * nch + src[c]] >> 8);
  } else {
    std::vector<uint8_t> buf(n * nch);
    if (!in->read(buf.data(), &error)) throw fail(oneLine(error));
    for (size_t i = 0; i < n; ++i)
      for (int c = 0; c < 3; ++c) out.pixels[i * 3 + c] = buf[i * nch + src[c]];
  }
  const int orientation = in->orientation;
  return applyOrientation(std::move(out), orientation);
}

RgbImage applyOrientation(RgbImage image, int orientation) {
  if (orientation < 2 || orientation > 8) return image;  // 1 (as stored) or not a valid tag
  const int w = image.width, h = image.height;
  const bool swap = orientation >= 5;  // transpose, rotations by 90 degrees, transverse
  RgbImage out;
  out.width = swap ? h : w;
  out.height = swap ? w : h;
  out.pixels.resize(image.pixels.size());
  for (int y = 0; y < out.height; ++y)
    for (int x = 0; x < out.width; ++x) {
      int sx = x, sy = y;  // the stored pixel shown at (x, y)
      switch (orientation) {
        case 2: sx = w - 1 - x; break;                    // mirrored left-right
        case 3: sx = w - 1 - x; sy = h - 1 - y; break;    // rotated 180
        case 4: sy = h - 1 - y; break;                    // mirrored top-bottom
        case 5: sx = y; sy = x; break;                    // transposed
        case 6: sx = y; sy = h - 1 - x; break;            // shown rotated 90 clockwise
        case 7: sx = w - 1 - y; sy = h - 1 - x; break;    // transverse
        case 8: sx = w - 1 - y; sy = x; break;            // shown rotated 90 counter-clockwise
      }
      for (int c = 0; c < 3; ++c)
        out.pixels[(size_t(y) * out.width + x) * 3 + c] = image.pixels[(size_t(sy) * w + sx) * 3 + c];
    }
  return out;
}

RgbImage resizeLanczos(const RgbImage& image, int newWidth, int newHeight) {
  const int w = image.width, h = image.height;
  if (w < 1 || h < 1 || image.pixels.size() != size_t(w) * h * 3)
    throw Error("resizeLanczos: image of " + std::to_string(w) + "x" + std::to_string(h) + " with " +
                std::to_string(image.pixels.size()) + " bytes");
  if (newWidth < 1 || newHeight < 1)
    throw Error("resizeLanczos: output size " + std::to_string(newWidth) + "x" + std::to_string(newHeight));

  const bool needH = newWidth != w, needV = newHeight != h;
  const Coeffs cv = precompute(h, newHeight);
  // Rows of the source the vertical pass reads.
  const int yFirst = cv.first[0];
  const int yLast = cv.first[newHeight - 1] + cv.count[newHeight - 1];
  constexpr int32_t kHalf = 1 << (kPrecisionBits - 1);

  RgbImage cur;
  int rowOffset = 0;  // row of `cur` that is row 0 of the source rows used
  if (needH) {
    const Coeffs ch = precompute(w, newWidth);
    const int rows = yLast - yFirst;
    cur.width = newWidth;
    cur.height = rows;
    cur.pixels.resize(size_t(newWidth) * rows * 3);
    for (int y = 0; y < rows; ++y) {
      const uint8_t* srcRow = image.pixels.data() + size_t(y + yFirst) * w * 3;
      uint8_t* dstRow = cur.pixels.data() + size_t(y) * newWidth * 3;
      for (int xx = 0; xx < newWidth; ++xx) {
        const int32_t* k = ch.weights.data() + size_t(xx) * ch.ksize;
        const int xmin = ch.first[xx], cnt = ch.count[xx];
        int32_t s0 = kHalf, s1 = kHalf, s2 = kHalf;
        for (int x = 0; x < cnt; ++x) {
          const uint8_t* p = srcRow + size_t(x + xmin) * 3;
          s0 += p[0] * k[x];
          s1 += p[1] * k[x];
          s2 += p[2] * k[x];
        }
        dstRow[xx * 3 + 0] = clip8(s0);
        dstRow[xx * 3 + 1] = clip8(s1);
        dstRow[xx * 3 + 2] = clip8(s2);
      }
    }
    rowOffset = yFirst;
  } else {
    cur = image;
  }
  if (!needV) return cur;

  RgbImage out;
  out.width = cur.width;
  out.height = newHeight;
  out.pixels.resize(size_t(cur.width) * newHeight * 3);
  const size_t rowBytes = size_t(cur.width) * 3;
  for (int yy = 0; yy < newHeight; ++yy) {
    const int32_t* k = cv.weights.data() + size_t(yy) * cv.ksize;
    const int ymin = cv.first[yy] - rowOffset, cnt = cv.count[yy];
    uint8_t* dstRow = out.pixels.data() + size_t(yy) * rowBytes;
    for (size_t i = 0; i < rowBytes; ++i) {
      int32_t s = kHalf;
      for (int y = 0; y < cnt; ++y) s += cur.pixels[size_t(y + ymin) * rowBytes + i] * k[y];
      dstRow[i] = clip8(s);
    }
  }
  return out;
}

CropGeometry cropGeometry(int width, int height, int outWidth, int outHeight) {
  if (width < 1 || height < 1 || outWidth < 1 || outHeight < 1)
    throw Error("cropGeometry: sizes must be positive (image " + std::to_string(width) + "x" +
                std::to_string(height) + ", output " + std::to_string(outWidth) + "x" + std::to_string(outHeight) + ")");
  const double s = std::max(static_cast<double>(outHeight) / height, static_cast<double>(outWidth) / width);
  // Python's round(): half to even (nearbyint in the default rounding mode).
  CropGeometry g;
  g.resizedWidth = std::max(outWidth, static_cast<int>(std::nearbyint(width * s)));
  g.resizedHeight = std::max(outHeight, static_cast<int>(std::nearbyint(height * s)));
  g.left = (g.resizedWidth - outWidth) / 2;
  g.top = (g.resizedHeight - outHeight) / 2;
  return g;
}

std::vector<float> prepareImage(const RgbImage& rgb, int outHeight, int outWidth) {
  const CropGeometry g = cropGeometry(rgb.width, rgb.height, outWidth, outHeight);
  const bool resize = g.resizedWidth != rgb.width || g.resizedHeight != rgb.height;
  const RgbImage resized = resize ? resizeLanczos(rgb, g.resizedWidth, g.resizedHeight) : RgbImage();
  const RgbImage& img = resize ? resized : rgb;
  if (img.pixels.size() != size_t(img.width) * img.height * 3)
    throw Error("prepareImage: image of " + std::to_string(img.width) + "x" + std::to_string(img.height) +
                " with " + std::to_string(img.pixels.size()) + " bytes");
  const size_t plane = size_t(outHeight) * outWidth;
  std::vector<float> out(plane * 3);
  for (int y = 0; y < outHeight; ++y)
    for (int x = 0; x < outWidth; ++x) {
      const uint8_t* p = img.pixels.data() + (size_t(y + g.top) * img.width + (x + g.left)) * 3;
      for (int c = 0; c < 3; ++c)
        out[c * plane + size_t(y) * outWidth + x] = static_cast<float>(p[c] / 255.0);  // as float64 / 255 -> f32
    }
  return out;
}

std::vector<float> loadPreparedImage(const std::string& path, int outHeight, int outWidth) {
  return prepareImage(loadImageRGB(path), outHeight, outWidth);
}

uint8_t toUint8(double x) {
  if (!(x > 0.0)) return 0;  // also NaN
  if (x >= 1.0) return 255;
  return static_cast<uint8_t>(std::floor(x * 255.0 + 0.5));
}

namespace {

void writePngBytes(const std::string& path, const uint8_t* data, int channels, int height, int width) {
  const fs::path target(path);
  const fs::path tmp = target.parent_path() / (target.filename().string() + ".tmp" + std::to_string(::getpid()) + ".png");
  std::string error;
  if (!writePng8(tmp.string(), data, channels, height, width, &error)) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw Error("cannot write PNG " + path + ": " + oneLine(error));
  }
  std::error_code ec;
  fs::rename(tmp, target, ec);
  if (ec) {
    std::error_code ignored;
    fs::remove(tmp, ignored);
    throw Error("cannot write PNG " + path + ": rename failed: " + ec.message());
  }
}

}  // namespace

void writePng(const std::string& path, const float* values, int channels, int height, int width) {
  if (channels != 1 && channels != 3)
    throw Error("writePng " + path + ": channels must be 1 or 3, not " + std::to_string(channels));
  if (height < 1 || width < 1)
    throw Error("writePng " + path + ": size " + std::to_string(width) + "x" + std::to_string(height));
  const size_t plane = size_t(height) * width;
  std::vector<uint8_t> bytes(plane * channels);
  for (size_t i = 0; i < plane; ++i)
    for (int c = 0; c < channels; ++c) bytes[i * channels + c] = toUint8(values[c * plane + i]);
  writePngBytes(path, bytes.data(), channels, height, width);
}

void writePng(const std::string& path, const std::vector<float>& values, int channels, int height, int width) {
  if (height < 1 || width < 1 || values.size() != size_t(channels) * height * width)
    throw Error("writePng " + path + ": " + std::to_string(values.size()) + " values for " + std::to_string(channels) +
                "x" + std::to_string(height) + "x" + std::to_string(width));
  writePng(path, values.data(), channels, height, width);
}

void writePng(const std::string& path, const RgbImage& image) {
  if (image.width < 1 || image.height < 1 || image.pixels.size() != size_t(image.width) * image.height * 3)
    throw Error("writePng " + path + ": image of " + std::to_string(image.width) + "x" +
                std::to_string(image.height) + " with " + std::to_string(image.pixels.size()) + " bytes");
  writePngBytes(path, image.pixels.data(), 3, image.height, image.width);
}

}  // namespace spar
