// Which files form the view sequence and which positions are inputs and targets, from the
// command line, as the reference's plan_views (reference/spar_reference/cli.py) decides it:
//   --images A B --targets C D     sequence A B C D, inputs 0 1, targets 2 3
//   --frames f0 .. f4 --inputs 0,3,4  all frames in capture order, the rest are targets
//   --video V [--video-frames N | --video-at T1,T2] [--inputs ...]  frames of a video, then as
//                                  --frames (planVideoViews, once the frame count is known)
// Only the command line is judged here (UsageError); the files are checked later.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

namespace spar::cli {

struct ViewArgs {
  std::vector<std::string> images, targets, frames;
  std::string inputs;           // "0,3,4" (with --frames or --video)
  bool targetsGiven = false;    // --targets appeared (even if CLI11 left it empty)
  std::string video;            // --video FILE
  int videoFrames = 0;          // --video-frames N (0: the model's view count)
  std::string videoAt;          // --video-at "T1,T2,..." seconds
};

// --video-at's times, parsed (UsageError for anything but non-negative seconds).
std::vector<double> parseVideoTimes(const std::string& text);

struct PlannedViews {
  std::vector<std::string> files;       // sequence order
  std::vector<int64_t> inputs, targets;  // increasing positions in files
};

// With --video the files stay empty: planVideoViews fills the plan once the frames are known.
PlannedViews planViews(const ViewArgs& args);
// The frames taken from a video (`names`, one per frame): --inputs as with --frames, by default
// `defaultInputs` positions spread evenly (first and last among them), the rest targets.
PlannedViews planVideoViews(const ViewArgs& args, const std::vector<std::string>& names, int64_t defaultInputs);

}  // namespace spar::cli
