// path.gif: the animation through OpenImageIO's GIF writer (one subimage per frame, appended as
// each frame arrives), so no external tool is needed. GIF's 256-colour palette quantizes.
#pragma once
#include <memory>
#include <string>

#include "imaging/image_files.h"
#include "tools/spar/animation.h"

namespace spar::cli {

class GifAnimation : public Animation {
 public:
  GifAnimation(const std::string& path, int fps, std::string note);
  ~GifAnimation() override;
  void add(const RgbImage& frame) override;
  void finish() override;
  std::string fileName() const override { return "path.gif"; }
  std::string description() const override;

 private:
  std::string path_, note_;
  int fps_ = 0;
  std::unique_ptr<AnimationFileWriter> out_;
  int width_ = 0, height_ = 0;
};

}  // namespace spar::cli
