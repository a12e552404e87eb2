// The module spar_image_files.so: imaging/image_files.h on OpenImageIO. It is the only code
// that includes OpenImageIO; the engine loads it on first use (image_files_loader.cpp).
#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>
#include <OpenImageIO/imageio.h>

#include "imaging/image_files.h"

namespace spar {
namespace {

bool failed(std::string* error, std::string message) {
  *error = message.empty() ? std::string("unknown error") : std::move(message);
  return false;
}

class OiioReader : public ImageFileReader {
 public:
  explicit OiioReader(std::unique_ptr<OIIO::ImageInput> in) : in_(std::move(in)) {
    const OIIO::ImageSpec& spec = in_->spec();
    width = spec.width;
    height = spec.height;
    depth = spec.depth;
    channels = spec.nchannels;
    sixteenBit = spec.format == OIIO::TypeDesc::UINT16 || spec.format == OIIO::TypeDesc::INT16;
    orientation = spec.get_int_attribute("Orientation", 1);
  }
  ~OiioReader() override { in_->close(); }
  bool read(void* pixels, std::string* error) override {
    if (in_->read_image(0, 0, 0, channels, sixteenBit ? OIIO::TypeDesc::UINT16 : OIIO::TypeDesc::UINT8, pixels))
      return true;
    return failed(error, in_->geterror());
  }

 private:
  std::unique_ptr<OIIO::ImageInput> in_;
};

class OiioAnimation : public AnimationFileWriter {
 public:
  OiioAnimation(std::unique_ptr<OIIO::ImageOutput> out, std::string path, OIIO::ImageSpec spec)
      : out_(std::move(out)), path_(std::move(path)), spec_(std::move(spec)) {}
  ~OiioAnimation() override {
    if (out_ && opened_) out_->close();
  }
  bool add(const uint8_t* rgb, std::string* error) override {
    if (!out_->open(path_, spec_, opened_ ? OIIO::ImageOutput::AppendSubimage : OIIO::ImageOutput::Create))
      return failed(error, out_->geterror());
    opened_ = true;
    return out_->write_image(OIIO::TypeDesc::UINT8, rgb) || failed(error, out_->geterror());
  }
  bool close(std::string* error) override {
    const bool ok = out_->close();
    opened_ = false;
    return ok || failed(error, out_->geterror());
  }

 private:
  std::unique_ptr<OIIO::ImageOutput> out_;
  std::string path_;
  OIIO::ImageSpec spec_;
  bool opened_ = false;
};

class OiioImageFiles : public ImageFiles {
 public:
  std::unique_ptr<ImageFileReader> open(const std::string& path, std::string* error) const override {
    OIIO::ImageSpec config;
    config.attribute("oiio:UnassociatedAlpha", 1);  // PNG/TIFF alpha as stored (PIL drops it as is)
    auto in = OIIO::ImageInput::open(path, &config);
    if (!in) {
      failed(error, OIIO::geterror());
      return nullptr;
    }
    return std::make_unique<OiioReader>(std::move(in));
  }

  bool writeFloats(const std::string& path, int width, int height, int channels, bool half, const float* values,
                   const std::vector<std::string>& channelNames, const std::string& compression,
                   std::string* error) const override {
    auto out = OIIO::ImageOutput::create(path);
    if (!out) return failed(error, OIIO::geterror());
    OIIO::ImageSpec spec(width, height, channels, half ? OIIO::TypeDesc::HALF : OIIO::TypeDesc::FLOAT);
    spec.channelnames = channelNames;
    spec.attribute("compression", compression);
    if (!out->open(path, spec)) return failed(error, out->geterror());
    const bool written = out->write_image(OIIO::TypeDesc::FLOAT, values);
    const bool closed = out->close();
    return (written && closed) || failed(error, out->geterror());
  }

  bool drawText(uint8_t* rgb, int width, int height, int x, int y, const std::string& text, int fontSize,
                const std::string& fontFile, std::string* error) const override {
    OIIO::ImageBuf buf(OIIO::ImageSpec(width, height, 3, OIIO::TypeDesc::UINT8), rgb);
    const float white[3] = {1.0f, 1.0f, 1.0f};
    return OIIO::ImageBufAlgo::render_text(buf, x, y, text, fontSize, fontFile, white) || failed(error, buf.geterror());
  }

  std::unique_ptr<AnimationFileWriter> openAnimation(const std::string& path, int width, int height, int fps,
                                                     std::string* error) const override {
    auto out = OIIO::ImageOutput::create(path);
    if (!out) {
      failed(error, OIIO::geterror());
      return nullptr;
    }
    if (!out->supports("multiimage") || !out->supports("appendsubimage")) {
      failed(error, "this OpenImageIO writes no animated GIF");
      return nullptr;
    }
    OIIO::ImageSpec spec(width, height, 3, OIIO::TypeDesc::UINT8);
    const int rate[2] = {fps, 1};
    spec.attribute("FramesPerSecond", OIIO::TypeRational, rate);
    spec.attribute("oiio:Movie", 1);
    spec.attribute("oiio:LoopCount", 0);  // loop forever
    return std::make_unique<OiioAnimation>(std::move(out), path, std::move(spec));
  }
};

}  // namespace
}  // namespace spar

extern "C" __attribute__((visibility("default"))) const spar::ImageFiles* spar_image_files_v1() {
  static const spar::OiioImageFiles files;
  return &files;
}
