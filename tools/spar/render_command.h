// `spar render`: one SPAR run on a sequence of views, written as the reference's
// `spar-reference render` writes it (reference/spar_reference/cli.py Run.write_render):
//   view_XX.png    rendered views (targets, --path or --cameras cameras), in order
//   motion_XX.png  P(dynamic) of each input view, 8-bit grey   (not with --assume-static)
//   mask_XX.png    P(dynamic) > mask threshold as 0 / 255       (not with --assume-static)
//   refined_XX.png with --refine / --mask-source refined: the SAM2.1-refined mask as 0 / 255
//   target_XX.png  with --path / --cameras and target frames: each target rendered with its
//                  estimated camera (with targets alone the views are the targets)
//   truth_XX.png   each target frame as the model saw it, for the page's comparison
//   path.mp4       with --path: the views (beside their label maps) as an H.264 video, when
//                  ffmpeg is installed (--animation auto|mp4); path.gif otherwise (--animation gif)
//   cameras.json   every view's estimated camera (nerfstudio convention), order, render cameras
//   colmap/        the same estimated cameras as a COLMAP text model (formats/colmap.h)
//   colmap_render/ with --path / --cameras: the rendered cameras as a COLMAP text model
//   report.json    device, precision, views, total time, the stages that ran with GPU times,
//                  each target's PSNR beside the nearest input's
// Everything the command line names is checked before any work; the directory appears only
// when complete (StagedDir). Only the public library (include/spar/) runs the model.
#pragma once
#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include "spar/context.h"
#include "spar/model.h"
#include "tools/spar/view_plan.h"

namespace spar::cli {

struct RenderArgs {
  std::string model;
  ViewArgs views;
  std::string cameras;             // --cameras transforms.json | COLMAP model dir | images.txt
  std::optional<int> path;         // --path N
  bool assumeStatic = false;
  bool refine = false;             // --refine: SAM2.1 refinement of the inputs' motion masks
  std::string maskSource = "raw";  // --mask-source raw | refined: which masks gate the input tokens
  std::string precision = "fp32";  // fp32 | fp16 | q8 | q4 (spar/precision.h)
  int64_t height = 0, width = 0;   // --size HxW; 0: the model's image size (its training size)
  std::string out;
  std::string device;              // index or part of the name; "" = SPAR_DEVICE / default
  std::optional<std::string> labels;
  bool features = false;
  bool scores = false;          // with --labels: per-label score maps (scores_XX.npy)
  std::string format = "png";  // --format png | exr | exr16 | npy (view_XX files)
  std::string animation = "auto";  // --animation auto | mp4 | gif: the --path animation
};

// What consecutive renders of one process share (spar render --jobs): the device with its
// compiled kernels, opened by the first render, and the last model opened.
struct RenderContext {
  std::unique_ptr<Context> context;
  std::shared_ptr<const Model> model;
};

// Throws UsageError (exit 2) or spar::Error (exit 1); prints progress on stderr. With `shared`,
// the device and model are taken from it (and left in it for the next render).
void runRender(const RenderArgs& args, RenderContext* shared = nullptr);

}  // namespace spar::cli
