// Which files form the view sequence and which positions are inputs and targets, from the
// command line, as the reference's plan_views (converter/spar_reference/cli.py) decides it:
//   --images A B --targets C D     sequence A B C D, inputs 0 1, targets 2 3
//   --frames f0 .. f4 --inputs 0,3,4  all frames in capture order, the rest are targets
// Only the command line is judged here (UsageError); the files are checked later.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

namespace spar::cli {

struct ViewArgs {
  std::vector<std::string> images, targets, frames;
  std::string inputs;           // "0,3,4" (with --frames)
  bool targetsGiven = false;    // --targets appeared (even if CLI11 left it empty)
};

struct PlannedViews {
  std::vector<std::string> files;       // sequence order
  std::vector<int64_t> inputs, targets;  // increasing positions in files
};

PlannedViews planViews(const ViewArgs& args);

}  // namespace spar::cli
