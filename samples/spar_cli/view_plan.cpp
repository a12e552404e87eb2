#include "samples/spar_cli/view_plan.h"

#include <algorithm>
#include <cctype>
#include <set>

#include "samples/spar_cli/errors.h"

namespace spar::cli {
namespace {

// "0, 3,4" -> {0, 3, 4}; anything else than comma-separated integers is refused.
std::vector<int64_t> parsePositions(const std::string& text) {
  std::vector<int64_t> out;
  std::string item;
  auto flush = [&]() {
    if (item.empty()) return;  // "0,,3" and a trailing comma are tolerated, as in the reference
    size_t used = 0;
    int64_t v = 0;
    try {
      v = std::stoll(item, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used != item.size()) throw UsageError("--inputs must be comma-separated frame positions, got '" + text + "'");
    out.push_back(v);
    item.clear();
  };
  for (char ch : text) {
    if (ch == ',') {
      flush();
    } else if (!std::isspace(static_cast<unsigned char>(ch))) {
      item += ch;
    }
  }
  flush();
  return out;
}

}  // namespace

PlannedViews planViews(const ViewArgs& a) {
  PlannedViews p;
  if (a.images.empty() && a.frames.empty()) throw UsageError("give the views with --images (then --targets) or --frames with --inputs");
  if (!a.images.empty()) {
    if (!a.inputs.empty())
      throw UsageError("--inputs goes with --frames; with --images the inputs are the --images");
    if (a.targetsGiven && a.targets.empty()) throw UsageError("--targets needs at least one image");
    p.files = a.images;
    p.files.insert(p.files.end(), a.targets.begin(), a.targets.end());
    for (size_t i = 0; i < a.images.size(); ++i) p.inputs.push_back(int64_t(i));
    for (size_t i = a.images.size(); i < p.files.size(); ++i) p.targets.push_back(int64_t(i));
  } else {
    if (a.targetsGiven)
      throw UsageError("--targets goes with --images; with --frames the frames not in --inputs are the targets");
    if (a.inputs.empty()) throw UsageError("--frames needs --inputs (e.g. --inputs 0,3,4)");
    p.files = a.frames;
    std::vector<int64_t> in = parsePositions(a.inputs);
    if (std::set<int64_t>(in.begin(), in.end()).size() != in.size())
      throw UsageError("--inputs repeats a position: " + a.inputs);
    for (int64_t i : in)
      if (i < 0 || i >= int64_t(p.files.size()))
        throw UsageError("--inputs position " + std::to_string(i) + " is outside the " + std::to_string(p.files.size()) +
                         " frames");
    std::sort(in.begin(), in.end());
    p.inputs = in;
    for (int64_t i = 0; i < int64_t(p.files.size()); ++i)
      if (!std::binary_search(in.begin(), in.end(), i)) p.targets.push_back(i);
    // --frames exists to say which frames are targets; all of them as inputs is a slip
    // (inputs only: --images).
    if (p.targets.empty() && !in.empty())
      throw UsageError("--inputs lists every frame, which leaves no target (for inputs only use --images)");
  }
  if (p.inputs.size() < 2) throw UsageError("need at least 2 input views, got " + std::to_string(p.inputs.size()));
  return p;
}

}  // namespace spar::cli
