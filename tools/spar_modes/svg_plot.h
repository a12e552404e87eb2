// A labelled scatter plot as a standalone SVG document (no plotting library on the machines:
// Debian's python3-matplotlib is not installed, and the report is a C++ program).
#pragma once
#include <string>
#include <vector>

namespace spar::modes {

struct PlotPoint {
  std::string label;
  double x = 0, y = 0;
};

// Points with finite coordinates are drawn; the others are listed under the plot as not shown.
std::string scatterSvg(const std::string& title, const std::string& xLabel, const std::string& yLabel,
                       const std::vector<PlotPoint>& points);

}  // namespace spar::modes
