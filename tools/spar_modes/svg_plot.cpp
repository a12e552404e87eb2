#include "tools/spar_modes/svg_plot.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace spar::modes {
namespace {

constexpr double kWidth = 640, kHeight = 420;
constexpr double kLeft = 80, kRight = 30, kTop = 40, kBottom = 70;
const char* const kColours[] = {"#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b"};

std::string escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    if (c == '<') out += "&lt;";
    else if (c == '>') out += "&gt;";
    else if (c == '&') out += "&amp;";
    else if (c == '"') out += "&quot;";
    else out += c;
  }
  return out;
}

std::string num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.1f", v);
  return buf;
}

// Axis range padded by 10% (not below zero for values that are not) and rounded to a tick step
// of 1, 2 or 5 times a power of ten (about five ticks).
struct Axis {
  double lo, hi, step;
  Axis(double mn, double mx) {
    const bool nonNegative = mn >= 0;
    if (mx - mn < 1e-9 * std::max(1.0, std::abs(mx))) {
      const double pad = std::max(1.0, std::abs(mx) * 0.1);
      mn -= pad;
      mx += pad;
    }
    const double pad = 0.1 * (mx - mn);
    mn -= pad;
    mx += pad;
    const double raw = (mx - mn) / 5, mag = std::pow(10.0, std::floor(std::log10(raw)));
    step = raw / mag < 1.5 ? mag : raw / mag < 3.5 ? 2 * mag : raw / mag < 7.5 ? 5 * mag : 10 * mag;
    lo = std::floor(mn / step) * step;
    if (nonNegative) lo = std::max(lo, 0.0);  // no negative times
    hi = std::ceil(mx / step) * step;
  }
  double to(double v, double a, double b) const { return a + (v - lo) / (hi - lo) * (b - a); }
};

std::string tickText(double v, double step) {
  char buf[32];
  const int decimals = step >= 1 ? 0 : int(std::ceil(-std::log10(step)));
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}

}  // namespace

std::string scatterSvg(const std::string& title, const std::string& xLabel, const std::string& yLabel,
                       const std::vector<PlotPoint>& points) {
  std::vector<const PlotPoint*> shown, hidden;
  for (const PlotPoint& p : points) (std::isfinite(p.x) && std::isfinite(p.y) ? shown : hidden).push_back(&p);
  double xmin = 0, xmax = 1, ymin = 0, ymax = 1;
  if (!shown.empty()) {
    auto [x0, x1] = std::minmax_element(shown.begin(), shown.end(), [](auto a, auto b) { return a->x < b->x; });
    auto [y0, y1] = std::minmax_element(shown.begin(), shown.end(), [](auto a, auto b) { return a->y < b->y; });
    xmin = std::min(0.0, (*x0)->x);  // time axis from zero: ratios read off directly
    xmax = (*x1)->x;
    ymin = (*y0)->y;
    ymax = (*y1)->y;
  }
  const Axis ax(xmin, xmax), ay(ymin, ymax);
  const double x0 = kLeft, x1 = kWidth - kRight, y0 = kHeight - kBottom, y1 = kTop;
  std::string s = "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" + num(kWidth) + "\" height=\"" +
                  num(kHeight) + "\" font-family=\"sans-serif\" font-size=\"12\">\n";
  s += "<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  s += "<text x=\"" + num(kWidth / 2) + "\" y=\"22\" text-anchor=\"middle\" font-size=\"15\">" + escape(title) +
       "</text>\n";
  // grid, ticks and labels
  for (double v = ax.lo; v <= ax.hi + ax.step / 2; v += ax.step) {
    const double x = ax.to(v, x0, x1);
    s += "<line x1=\"" + num(x) + "\" y1=\"" + num(y0) + "\" x2=\"" + num(x) + "\" y2=\"" + num(y1) +
         "\" stroke=\"#ddd\"/>\n<text x=\"" + num(x) + "\" y=\"" + num(y0 + 16) + "\" text-anchor=\"middle\">" +
         tickText(v, ax.step) + "</text>\n";
  }
  for (double v = ay.lo; v <= ay.hi + ay.step / 2; v += ay.step) {
    const double y = ay.to(v, y0, y1);
    s += "<line x1=\"" + num(x0) + "\" y1=\"" + num(y) + "\" x2=\"" + num(x1) + "\" y2=\"" + num(y) +
         "\" stroke=\"#ddd\"/>\n<text x=\"" + num(x0 - 6) + "\" y=\"" + num(y + 4) + "\" text-anchor=\"end\">" +
         tickText(v, ay.step) + "</text>\n";
  }
  s += "<rect x=\"" + num(x0) + "\" y=\"" + num(y1) + "\" width=\"" + num(x1 - x0) + "\" height=\"" + num(y0 - y1) +
       "\" fill=\"none\" stroke=\"black\"/>\n";
  s += "<text x=\"" + num((x0 + x1) / 2) + "\" y=\"" + num(y0 + 38) + "\" text-anchor=\"middle\">" + escape(xLabel) +
       "</text>\n";
  s += "<text transform=\"translate(20," + num((y0 + y1) / 2) + ") rotate(-90)\" text-anchor=\"middle\">" +
       escape(yLabel) + "</text>\n";
  std::vector<std::pair<double, double>> placed;  // label anchors so far
  for (size_t i = 0; i < shown.size(); ++i) {
    const double x = ax.to(shown[i]->x, x0, x1), y = ay.to(shown[i]->y, y0, y1);
    const char* colour = kColours[i % (sizeof kColours / sizeof kColours[0])];
    s += "<circle cx=\"" + num(x) + "\" cy=\"" + num(y) + "\" r=\"5\" fill=\"" + colour + "\"/>\n";
    // Labels left of points in the right half, so they stay inside the frame; moved down a line
    // while they would cover an earlier one (modes close in time and error).
    const bool left = x > (x0 + x1) / 2;
    const double lx = left ? x - 8 : x + 8;
    double ly = y - 8;
    for (bool moved = true; moved;) {
      moved = false;
      for (const auto& [px, py] : placed)
        if (std::abs(px - lx) < 90 && std::abs(py - ly) < 14) {
          ly = py + 14;
          moved = true;
        }
    }
    placed.emplace_back(lx, ly);
    s += "<text x=\"" + num(lx) + "\" y=\"" + num(ly) + "\" text-anchor=\"" + (left ? "end" : "start") +
         "\" fill=\"" + colour + "\">" + escape(shown[i]->label) + "</text>\n";
  }
  if (!hidden.empty()) {
    std::string names;
    for (const PlotPoint* p : hidden) names += (names.empty() ? "" : ", ") + p->label;
    s += "<text x=\"" + num(x0) + "\" y=\"" + num(kHeight - 8) + "\">not shown (no finite value): " + escape(names) +
         "</text>\n";
  }
  return s + "</svg>\n";
}

}  // namespace spar::modes
