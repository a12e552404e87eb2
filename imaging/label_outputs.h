// The label outputs of `spar render --labels`, as the reference writes them
// (reference/spar_reference/cli.py write_render, images.py save_label_map / palette_colour):
//
//   labels_XX.png   the map [h, w] in palette colours, scaled (nearest, PIL's rule) to the
//                   model's H x W, above a legend strip: 14 rows per label on black, each a
//                   colour swatch at x 2..12, y+1..y+11 (y = H + 2 + 14 k), image H + 14 P + 4 tall
//   labels_XX.json  {"view", "resolution": [h, w], "logit_scale", "legend": {label: "#rrggbb"},
//                    "labels": [{"index", "label", "colour": [r, g, b], "pixels", "share"}]},
//                   Python's json.dump(indent=1) layout (keys in this order, non-ASCII as \uXXXX)
//
// The names beside the swatches are drawn with DejaVu Sans through OpenImageIO (the reference
// uses PIL's built-in bitmap font, whose glyph data is Pillow's): the legend's text pixels are
// the only ones that differ from the reference's PNG.
#pragma once
#include <nlohmann/json.hpp>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "imaging/image_prep.h"

namespace spar {

// The TrueType font the legend's names are drawn with, or "" when it is not installed.
const std::string& legendFont();
// Draws each name right of its swatch (legend rows below the map, which is outH tall).
void drawLegendNames(RgbImage& img, const std::vector<std::string>& names, int outH);

// Label k's colour: the reference's fixed palette of 20, then (where the reference repeats
// them) a colour of its own for every further label, none black or a palette colour.
std::array<uint8_t, 3> paletteColour(int64_t k);

// The labels_XX.png image: map [h, w] (values in [0, names.size())) scaled to outH x outW.
RgbImage labelImage(const std::vector<int32_t>& map, int h, int w, const std::vector<std::string>& names, int outH,
                    int outW);
void writeLabelPng(const std::string& path, const std::vector<int32_t>& map, int h, int w,
                   const std::vector<std::string>& names, int outH, int outW);

// The scale of SPAR's label scores (LSeg's 1 / 0.07, model/label_maps.h): labels_XX.json records it.
double lsegLogitScale();
// The labels_XX.json document of view `view` (ordered as the reference writes it).
nlohmann::ordered_json labelJson(const std::vector<int32_t>& map, int h, int w, const std::vector<std::string>& names,
                                 int64_t view, double logitScale);
// Serialized as Python's json.dump(doc, f, indent=1) does (no trailing newline).
std::string labelJsonText(const nlohmann::ordered_json& doc);
void writeLabelJson(const std::string& path, const nlohmann::ordered_json& doc);

// Everything write_render writes for --labels: labels_XX.png and labels_XX.json (XX = view,
// two digits) in `dir` for maps [views, h, w] (row-major, as labelMaps downloads them), the
// PNGs at the model's outH x outW, the JSON with LSeg's logit scale.
void writeLabelFiles(const std::string& dir, const std::vector<int32_t>& maps, int views, int h, int w,
                     const std::vector<std::string>& names, int outH, int outW);

}  // namespace spar
