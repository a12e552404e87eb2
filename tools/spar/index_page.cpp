// index.html of a `spar render` output (index_page.h).
#include "tools/spar/index_page.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include "spar/error.h"
#include "tools/common/markup_escape.h"

namespace spar::cli {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::ordered_json;

std::string esc(const std::string& s) { return escapeMarkup(s); }

std::string num(double v, const char* fmt = "%.1f") {
  char b[64];
  std::snprintf(b, sizeof b, fmt, v);
  return b;
}

// The files of `dir` whose names start with `prefix` and end with `suffix`, sorted.
std::vector<std::string> files(const std::set<std::string>& names, const std::string& prefix, const std::string& suffix) {
  std::vector<std::string> out;
  for (const std::string& n : names)
    if (n.rfind(prefix, 0) == 0 && n.size() >= suffix.size() && n.compare(n.size() - suffix.size(), suffix.size(), suffix) == 0)
      out.push_back(n);
  return out;
}

std::string two(size_t i) {
  char b[24];
  std::snprintf(b, sizeof b, "%02zu", i);
  return b;
}

const char* kStyle = R"(body{font:14px/1.4 sans-serif;margin:1.5em;color:#222;max-width:1400px}
h1{font-size:1.4em;margin:0 0 .3em}h2{font-size:1.1em;margin:1.4em 0 .5em;border-bottom:1px solid #ddd}
.meta{color:#555}.grid{display:flex;flex-wrap:wrap;gap:12px}figure{margin:0}figcaption{font-size:12px;color:#555;max-width:260px}
img,video{image-rendering:pixelated;width:192px;height:auto;border:1px solid #ccc;display:block}
.stack{position:relative;width:192px}.stack img.mask{position:absolute;left:0;top:0;filter:url(#mask-red);opacity:.6}.warn li{color:#a40}.swatch{display:inline-block;width:12px;
height:12px;margin-right:4px;vertical-align:middle;border:1px solid #999}.legend span.l{margin-right:14px;white-space:nowrap}
svg text{font:11px sans-serif}.input{fill:#1f77b4}.target{fill:#ff7f0e}.render{fill:#2ca02c}
.note{background:#fff4d6;border:1px solid #e0c060;padding:.5em .8em}img.map{object-fit:cover;object-position:top}
)";

// Where the model note's link leads: how to render with the paper's weights instead of a
// demonstration model (README.md and docs/checkpoints.md say the same).
const char* kOfficialWeightsSection = R"(<h2 id="official-weights">The official weights</h2>
<p>The engine runs the paper's released SPAR model. Convert its checkpoint with the engine's converter
(no PyTorch needed), then render with it:</p>
<pre>converter/spar-convert ckpt_spar_XXX.pt --config spar.yaml --dino dinov3_vitb16_pretrain_lvd1689m.pth \
    --lseg demo_e200.ckpt -o spar.spar
spar render --model spar.spar --images a.jpg b.jpg c.jpg --path 24 --labels "wall,floor,sofa,person" --out out/mine</pre>
<p>Which files those are and where they come from: docs/checkpoints.md in the engine's repository.</p>
)";

// The run's warnings (the CLI's lines), or "none".
std::string warningList(const std::vector<std::string>& warnings) {
  if (warnings.empty()) return "<p id=\"warnings\">none</p>\n";
  std::string out = "<ul id=\"warnings\" class=\"warn\">";
  for (const std::string& w : warnings) out += "<li>" + esc(w) + "</li>";
  return out + "</ul>\n";
}

// Top-down (x right, z forward: OpenCV axes seen from above) plot of every camera: a dot and a
// short line along its viewing direction; inputs blue, targets orange, rendered cameras green.
std::string cameraPlot(const json& cameras) {
  struct Cam {
    double x, z, dx, dz;
    std::string role, title;
  };
  std::vector<Cam> cams;
  auto add = [&](const json& f, const std::string& role) {
    const auto m = f.at("c2w_opencv").get<std::vector<std::vector<double>>>();
    const double dx = m[0][2], dz = m[2][2], n = std::hypot(dx, dz);
    std::string title = role + " " + std::to_string(f.value("index", 0));
    if (f.contains("file_path")) title += ": " + f["file_path"].get<std::string>();
    cams.push_back({m[0][3], m[2][3], n > 0 ? dx / n : 0, n > 0 ? dz / n : 1, role, title});
  };
  for (const auto& f : cameras.value("frames", json::array())) add(f, f.value("role", "input") == "input" ? "input" : "target");
  for (const auto& f : cameras.value("render_frames", json::array())) add(f, "render");
  double x0 = 0, x1 = 0, z0 = 0, z1 = 0;
  for (const Cam& c : cams) {
    x0 = std::min(x0, c.x), x1 = std::max(x1, c.x), z0 = std::min(z0, c.z), z1 = std::max(z1, c.z);
  }
  const double span = std::max({x1 - x0, z1 - z0, 1e-6}), pad = 0.25 * span + 1e-6;
  const double size = 360, scale = size / (span + 2 * pad);
  auto px = [&](double x) { return (x - x0 + pad + (span - (x1 - x0)) / 2) * scale; };
  // z forward points up the page
  auto pz = [&](double z) { return size - (z - z0 + pad + (span - (z1 - z0)) / 2) * scale; };
  std::ostringstream s;
  s << "<svg id=\"camera-plot\" width=\"" << size << "\" height=\"" << size << "\" viewBox=\"0 0 " << size << " "
    << size << "\" role=\"img\" aria-label=\"cameras seen from above\">"
    << "<rect width=\"" << size << "\" height=\"" << size << "\" fill=\"#fafafa\" stroke=\"#ccc\"/>";
  const double arrow = 0.12 * span * scale + 8;
  for (const Cam& c : cams) {
    const double x = px(c.x), y = pz(c.z);
    s << "<line x1=\"" << num(x) << "\" y1=\"" << num(y) << "\" x2=\"" << num(x + c.dx * arrow) << "\" y2=\""
      << num(y - c.dz * arrow) << "\" stroke=\"#888\"/>";
    s << "<circle class=\"cam " << c.role << "\" cx=\"" << num(x) << "\" cy=\"" << num(y) << "\" r=\""
      << (c.role == "render" ? 3 : 5) << "\"><title>" << esc(c.title) << "</title></circle>";
  }
  s << "</svg><p class=\"meta\"><span style=\"color:#1f77b4\">● inputs</span> <span style=\"color:#ff7f0e\">● targets"
    << "</span> <span style=\"color:#2ca02c\">● rendered cameras</span>; seen from above: x right, z (forward) up</p>";
  return s.str();
}

// Stage times as horizontal bars: compute (GPU timestamps), driver builds, wall.
std::string timeBars(const json& report) {
  const json stages = report.value("stages", json::array());
  double most = 1e-9;
  for (const auto& st : stages) most = std::max(most, st.value("wall_ms", 0.0));
  const double width = 420, row = 18, left = 120;
  std::ostringstream s;
  s << "<svg id=\"stage-times\" width=\"" << left + width + 80 << "\" height=\"" << row * (stages.size() + 1) + 8
    << "\" role=\"img\" aria-label=\"stage times\">";
  size_t i = 0;
  for (const auto& st : stages) {
    const double y = 4 + row * double(i++);
    const double wall = st.value("wall_ms", 0.0), gpu = st.value("gpu_ms", 0.0), build = st.value("build_ms", 0.0);
    auto bar = [&](double ms, double offset, const char* colour) {
      s << "<rect x=\"" << num(left + offset / most * width) << "\" y=\"" << y << "\" width=\"" << num(ms / most * width, "%.2f")
        << "\" height=\"" << row - 5 << "\" fill=\"" << colour << "\"/>";
    };
    s << "<text x=\"0\" y=\"" << y + 11 << "\">" << esc(st.value("name", "")) << "</text>";
    bar(wall, 0, "#ddd");
    bar(gpu, 0, "#1f77b4");
    bar(build, gpu, "#ff7f0e");
    s << "<text x=\"" << num(left + wall / most * width + 4) << "\" y=\"" << y + 11 << "\">" << num(wall) << " ms</text>";
  }
  s << "<text x=\"0\" y=\"" << row * double(stages.size()) + 16 << "\"><tspan fill=\"#1f77b4\">■ compute</tspan>  "
    << "<tspan fill=\"#ff7f0e\">■ driver builds</tspan>  <tspan fill=\"#999\">■ wall</tspan></text></svg>";
  return s.str();
}

// The page's title, the run's facts, the model note, the warnings.
void writeHeader(std::ostringstream& h, const IndexPageInputs& in) {
  const json& report = in.report;
  const json views = report.value("views", json::object());
  const json size = report.value("image_size", json::object());
  h << "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>spar render: "
    << views.value("rendered", 0) << " views</title>\n<style>" << kStyle << "</style></head>\n<body>\n";
  // The masks (0 / 255 grey) drawn as translucent red over their inputs: luminance -> red's alpha.
  h << "<svg width=\"0\" height=\"0\" style=\"position:absolute\"><filter id=\"mask-red\"><feColorMatrix "
       "type=\"matrix\" values=\"0 0 0 0 1  0 0 0 0 0  0 0 0 0 0  0.333 0.333 0.333 0 0\"/></filter></svg>\n";
  h << "<h1>spar render</h1>\n<p class=\"meta\">model <b>" << esc(report.value("model", "")) << "</b><br>device <b>"
    << esc(report.value("device", "")) << "</b>, precision <b>" << esc(report.value("precision", "")) << "</b>, "
    << size.value("height", 0) << "x" << size.value("width", 0) << " (HxW) from " << esc(size.value("from", "")) << "<br>"
    << views.value("total", 0) << " views: " << views.value("inputs", 0) << " inputs, " << views.value("targets", 0)
    << " targets; rendered " << views.value("rendered", 0) << " (" << esc(report.value("render", "")) << "), "
    << num(report.value("total_seconds", 0.0), "%.2f") << " s in all</p>\n";
  // What the model file says it is (a demonstration model's card), first: its renders show the
  // model's quality, not the engine's; the same sentence `spar render` printed.
  if (in.note)
    h << "<p id=\"model-note\" class=\"note\">" << esc(in.note->claim) << "; " << esc(in.note->when)
      << "<a href=\"#official-weights\">" << esc(in.note->action) << "</a>.</p>\n";
  h << "<h2>Warnings</h2>\n";
  h << warningList(in.warnings);
}

// Each input with its motion mask over it, P(dynamic) below, and SAM2.1's mask when refined.
void writeInputs(std::ostringstream& h, const std::set<std::string>& names, const IndexPageInputs& in) {
  std::vector<std::string> inputFiles;
  for (const auto& f : in.cameras.value("frames", json::array()))
    if (f.value("role", "") == "input") inputFiles.push_back(f.value("file_path", ""));
  const auto inputs = files(names, "input_", ".png");
  if (inputs.empty()) return;
  // --refine: per input view what SAM2.1 decided (report.json "refine"), its mask beside CV-DRP's
  const json refineViews = in.report.contains("refine") && in.report["refine"].is_object()
                               ? in.report["refine"].value("views", json::array())
                               : json::array();
  h << "<h2>Inputs, with their motion masks over them</h2>\n<div class=\"grid\">";
  for (size_t k = 0; k < inputs.size(); ++k) {
    const std::string mask = "mask_" + two(k) + ".png", motion = "motion_" + two(k) + ".png",
                      refined = "refined_" + two(k) + ".png";
    auto overlay = [&](const std::string& file, const std::string& alt) {
      h << "<div class=\"stack\"><img src=\"" << inputs[k] << "\" alt=\"input " << k << "\">";
      if (names.count(file)) h << "<img class=\"mask\" src=\"" << file << "\" alt=\"" << alt << " " << k << "\">";
      h << "</div>";
    };
    h << "<figure>";
    overlay(mask, "motion mask");
    if (names.count(motion)) h << "<img src=\"" << motion << "\" alt=\"P(dynamic) of input " << k << "\">";
    if (names.count(refined)) overlay(refined, "SAM2.1-refined mask");
    h << "<figcaption>input " << k << (k < inputFiles.size() ? ": " + esc(fs::path(inputFiles[k]).filename().string()) : "")
      << (names.count(mask) ? "; red: moving (mask), grey below: P(dynamic)" : "");
    if (names.count(refined) && k < refineViews.size()) {
      const json& v = refineViews[k];
      h << "; last: refined by SAM2.1 ";
      if (v.value("skipped", false))
        h << "(skipped: " << v.value("dynamic_pixels", 0) << " dynamic pixels, the mask kept)";
      else
        h << "(mask " << v.value("chosen", -1) << " of 3, predicted IoU "
          << num(v.value("iou", json::array()).at(size_t(v.value("chosen", 0))).get<double>(), "%.3f") << ")";
    }
    h << "</figcaption></figure>";
  }
  h << "</div>\n";
}

// What the model was asked for and how close it came: each target frame's render beside the
// frame, with both PSNRs (report.json "targets"; target_scores.h).
void writeTargets(std::ostringstream& h, const std::set<std::string>& names, const json& report) {
  const json targets = report.value("targets", json::array());
  if (targets.empty()) return;
  auto db = [](const json& v) { return v.is_number() ? num(v.get<double>(), "%.2f") + " dB" : std::string("identical"); };
  double sum = 0, copySum = 0;
  size_t n = 0;
  for (const auto& t : targets)
    if (t["psnr"].is_number() && t["psnr_copy"].is_number()) sum += t["psnr"].get<double>(), copySum += t["psnr_copy"].get<double>(), ++n;
  h << "<h2>Targets: each render beside its frame</h2>\n<p id=\"target-summary\" class=\"meta\">Whole-image PSNR of "
    << "each target frame rendered from its estimated camera, and of copying the nearest input frame instead";
  if (n) h << "; mean " << num(sum / double(n), "%.2f") << " dB against " << num(copySum / double(n), "%.2f") << " dB";
  h << ". Moving people and pets count against both: the model renders the static scene.</p>\n<div class=\"grid\">";
  for (size_t j = 0; j < targets.size(); ++j) {
    const json& t = targets[j];
    const std::string render = "target_" + two(j) + ".png", truth = "truth_" + two(j) + ".png";
    if (!names.count(render) || !names.count(truth)) continue;
    h << "<figure class=\"target\"><div class=\"grid\"><img src=\"" << render << "\" alt=\"target " << j
      << " rendered\"><img src=\"" << truth << "\" alt=\"target " << j << " frame\"></div><figcaption>frame "
      << t.value("view", 0) << ": render " << db(t["psnr"]) << ", copying input frame " << t.value("nearest_input", 0)
      << " " << db(t["psnr_copy"]) << " (left: render, right: frame)</figcaption></figure>";
  }
  h << "</div>\n";
}

// The legend of every label map on the page (the same colours in all), with each label's share of
// view 0; the maps are shown without the legend strip their PNGs carry.
void writeLegend(std::ostringstream& h, const std::string& dir, const std::set<std::string>& names) {
  if (!names.count("labels_00.json")) return;
  std::ifstream in(fs::path(dir) / "labels_00.json");
  const json doc = json::parse(in, nullptr, false);
  if (doc.is_discarded() || !doc.contains("labels")) return;
  h << "<p id=\"legend\" class=\"legend\">Label maps: ";
  for (const auto& l : doc["labels"]) {
    const auto c = l.value("colour", std::vector<int>{0, 0, 0});
    h << "<span class=\"l\"><span class=\"swatch\" style=\"background:rgb(" << c[0] << "," << c[1] << "," << c[2]
      << ")\"></span>" << esc(l.value("label", "")) << " (" << num(100 * l.value("share", 0.0), "%.0f") << "% of view 0)</span> ";
  }
  h << "</p>\n";
}

// The rendered views (the animation first) with their label maps.
void writeViews(std::ostringstream& h, const std::string& dir, const std::set<std::string>& names, const json& report) {
  const json views = report.value("views", json::object());
  const json size = report.value("image_size", json::object());
  const auto pngViews = files(names, "view_", ".png");
  const size_t viewCount = size_t(views.value("rendered", 0));
  h << "<h2>Rendered views</h2>\n";
  if (names.count("path.mp4"))
    h << "<p><video src=\"path.mp4\" controls loop muted style=\"width:384px\"></video></p>\n";
  else if (names.count("path.gif"))
    h << "<p><img src=\"path.gif\" alt=\"the camera path\" style=\"width:384px\"></p>\n";
  const auto anyViews = files(names, "view_", "");
  if (pngViews.empty() && !anyViews.empty())
    h << "<p>" << viewCount << " views written as " << esc(fs::path(anyViews.front()).extension().string())
      << " files (float data: not shown here)</p>\n";
  writeLegend(h, dir, names);
  // A label PNG is the map (the render's H x W) above its legend strip: shown at the map's aspect
  // ratio from the top, the strip falls outside the box.
  const std::string mapAspect = std::to_string(size.value("width", 1)) + "/" + std::to_string(size.value("height", 1));
  h << "<div class=\"grid\">";
  for (size_t j = 0; j < pngViews.size(); ++j) {
    const std::string labels = "labels_" + two(j) + ".png";
    h << "<figure><img src=\"" << pngViews[j] << "\" alt=\"view " << j << "\">";
    if (names.count(labels))
      h << "<img class=\"map\" style=\"aspect-ratio:" << mapAspect << "\" src=\"" << labels << "\" alt=\"label map " << j << "\">";
    h << "<figcaption>view " << j << "</figcaption></figure>";
  }
  h << "</div>\n";
}

}  // namespace

std::string indexPage(const std::string& dir, const IndexPageInputs& in) {
  std::set<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) names.insert(e.path().filename().string());
  std::ostringstream h;
  writeHeader(h, in);
  writeInputs(h, names, in);
  writeTargets(h, names, in.report);
  writeViews(h, dir, names, in.report);
  h << "<h2>Cameras</h2>\n" << cameraPlot(in.cameras) << "\n";
  h << "<h2>Stage times</h2>\n" << timeBars(in.report) << "\n";
  if (in.note) h << kOfficialWeightsSection;
  // For people and tests alike: how many images loaded (a broken one shows as a count here).
  h << "<p id=\"loaded\" class=\"meta\"></p>\n<script>addEventListener('load',()=>{let ok=0,bad=0;"
       "for(const i of document.images)(i.naturalWidth>0?ok++:bad++);document.body.dataset.imagesLoaded=ok;"
       "document.body.dataset.imagesBroken=bad;document.getElementById('loaded').textContent=ok+' images shown'+"
       "(bad?', '+bad+' missing':'');});</script>\n</body></html>\n";
  return h.str();
}

std::string evalResultsPage(const json& result, const std::string& device, const std::vector<std::string>& warnings) {
  std::ostringstream h;
  h << "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>spar eval</title>\n<style>" << kStyle
    << "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}</style></head>\n<body>\n"
    << "<h1>spar eval</h1>\n<p class=\"meta\">model <b>" << esc(result.value("model", "")) << "</b><br>device <b>" << esc(device)
    << "</b>, precision <b>" << esc(result.value("precision", "")) << "</b>, mode <b>" << esc(result.value("mode", ""))
    << "</b><br>" << result.value("scenes", 0) << " scenes of " << result.value("frames", 0)
    << " frames (evaluation/PROTOCOL.md)</p>\n<h2>Warnings</h2>\n";
  h << warningList(warnings);
  std::vector<std::pair<const char*, const char*>> columns = {
      {"target_views", "targets"},     {"psnr", "PSNR"},           {"psnr_nearest_input", "PSNR copy"},
      {"psnr_mean_colour", "PSNR mean"}, {"ssim", "SSIM"},        {"ssim_nearest_input", "SSIM copy"},
      {"mask_miou", "mask mIoU"},      {"mask_iou_dynamic", "IoU dyn"}, {"mask_recall", "recall"}};
  if (result.value("refine", false))  // the paper's "w/ Refine" row beside CV-DRP's
    columns.insert(columns.end(), {{"refined_mask_miou", "refined mask mIoU"},
                                   {"refined_mask_iou_dynamic", "refined IoU dyn"},
                                   {"refined_mask_recall", "refined recall"}});
  columns.insert(columns.end(), {{"sem_miou", "sem mIoU"}, {"sem_accuracy", "sem acc"}, {"ms_per_scene", "ms/scene"}});
  h << "<h2>Results (copy: the nearest input copied; mean: its mean colour)</h2>\n<table id=\"results\"><tr><th>K inputs</th>";
  for (const auto& c : columns) h << "<th>" << c.second << "</th>";
  h << "</tr>";
  const json results = result.value("results", json::object());
  for (const auto& [k, r] : results.items()) {
    h << "<tr><td>" << esc(k) << "</td>";
    for (const auto& c : columns) {
      const json v = r.value(c.first, json());
      h << "<td>" << (v.is_number() ? num(v.get<double>(), std::string(c.first) == "target_views" ? "%.0f" : "%.3f") : "-")
        << "</td>";
    }
    h << "</tr>";
  }
  h << "</table>\n</body></html>\n";
  return h.str();
}

void writeIndexPage(const std::string& dir, const IndexPageInputs& in) {
  const std::string page = indexPage(dir, in);
  std::ofstream out(fs::path(dir) / "index.html", std::ios::binary);
  out << page;
  if (!out) throw Error("cannot write " + (fs::path(dir) / "index.html").string());
}

}  // namespace spar::cli
