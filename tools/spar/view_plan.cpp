#include "tools/spar/view_plan.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <set>

#include "tools/common/errors.h"

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

std::vector<double> parseVideoTimes(const std::string& text) {
  std::vector<double> out;
  std::string item;
  auto flush = [&]() {
    const size_t b = item.find_first_not_of(" \t"), e = item.find_last_not_of(" \t");
    if (b == std::string::npos) return;
    const std::string t = item.substr(b, e - b + 1);
    size_t used = 0;
    double v = -1;
    try {
      v = std::stod(t, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used != t.size() || !(v >= 0) || !std::isfinite(v))
      throw UsageError("--video-at must be comma-separated times in seconds (e.g. 0.5,2,3.25), got '" + text + "'");
    out.push_back(v);
    item.clear();
  };
  for (char ch : text) {
    if (ch == ',') flush();
    else item += ch;
  }
  flush();
  if (out.empty()) throw UsageError("--video-at needs at least one time");
  return out;
}

namespace {

// --inputs over `count` frames (positions checked, sorted), the rest targets.
void planPositions(PlannedViews& p, const std::string& inputs) {
  std::vector<int64_t> in = parsePositions(inputs);
  if (std::set<int64_t>(in.begin(), in.end()).size() != in.size())
    throw UsageError("--inputs repeats a position: " + inputs);
  for (int64_t i : in)
    if (i < 0 || i >= int64_t(p.files.size()))
      throw UsageError("--inputs position " + std::to_string(i) + " is outside the " + std::to_string(p.files.size()) +
                       " frames");
  std::sort(in.begin(), in.end());
  p.inputs = in;
  for (int64_t i = 0; i < int64_t(p.files.size()); ++i)
    if (!std::binary_search(in.begin(), in.end(), i)) p.targets.push_back(i);
}

}  // namespace

PlannedViews planVideoViews(const ViewArgs& a, const std::vector<std::string>& names, int64_t defaultInputs) {
  PlannedViews p;
  p.files = names;
  const int64_t n = int64_t(names.size());
  if (!a.inputs.empty()) {
    planPositions(p, a.inputs);
  } else {
    const int64_t k = std::min(std::max<int64_t>(defaultInputs, 2), n);
    std::set<int64_t> in;
    for (int64_t i = 0; i < k; ++i) in.insert(k > 1 ? int64_t(std::llround(double(i) * double(n - 1) / double(k - 1))) : 0);
    p.inputs.assign(in.begin(), in.end());
    for (int64_t i = 0; i < n; ++i)
      if (!in.count(i)) p.targets.push_back(i);
  }
  if (p.inputs.size() < 2)
    throw UsageError("need at least 2 input views, got " + std::to_string(p.inputs.size()) + " (take more frames: --video-frames)");
  return p;
}

PlannedViews planViews(const ViewArgs& a) {
  PlannedViews p;
  if (!a.video.empty()) {
    if (!a.images.empty() || !a.frames.empty() || a.targetsGiven)
      throw UsageError("--video gives the views: it excludes --images, --frames and --targets");
    if (a.videoFrames && !a.videoAt.empty()) throw UsageError("--video-frames and --video-at exclude each other");
    if (a.videoFrames < 0 || (a.videoFrames == 1)) throw UsageError("--video-frames needs at least 2 frames, got " + std::to_string(a.videoFrames));
    if (!a.videoAt.empty()) parseVideoTimes(a.videoAt);
    return p;
  }
  if (a.videoFrames || !a.videoAt.empty()) throw UsageError("--video-frames and --video-at go with --video");
  if (a.images.empty() && a.frames.empty()) throw UsageError("give the views with --images (then --targets), --frames with --inputs, or --video");
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
    planPositions(p, a.inputs);
    const std::vector<int64_t>& in = p.inputs;
    // --frames exists to say which frames are targets; all of them as inputs is a slip
    // (inputs only: --images).
    if (p.targets.empty() && !in.empty())
      throw UsageError("--inputs lists every frame, which leaves no target (for inputs only use --images)");
  }
  if (p.inputs.size() < 2) throw UsageError("need at least 2 input views, got " + std::to_string(p.inputs.size()));
  return p;
}

}  // namespace spar::cli
