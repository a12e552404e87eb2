// index.html of a `spar render` output directory: one self-contained page beside the files it
// shows (plain HTML, inline SVG and CSS, no network, readable from file://): the inputs with
// their motion masks over them, each target frame's render beside the frame with both PSNRs,
// the rendered views (and the path video), the label maps with
// their legend, a top-down plot of every camera, the stage times as bars, the run's warnings,
// and the model, device and precision. Written last, from what the directory holds and the
// run's report and cameras documents (tests/test_spar_index_page.cpp opens it in Chromium).
#pragma once
#include <nlohmann/json.hpp>

#include <optional>
#include <string>
#include <vector>

#include "spar/model.h"

namespace spar::cli {

// The page's HTML for the files in `dir` (view_XX.*, input_XX.png, motion_XX.png, mask_XX.png,
// labels_XX.png/.json, path.mp4 / path.gif), the run's report.json and cameras.json documents
// and its warnings (the CLI's own lines, without the "spar: warning: " prefix).
struct IndexPageInputs {
  nlohmann::ordered_json report, cameras;
  std::vector<std::string> warnings;
  std::optional<DemonstrationNote> note;  // the model's, when it is a demonstration model
};
std::string indexPage(const std::string& dir, const IndexPageInputs& in);

// The results page of `spar eval` (result.json's document, the device it ran on, its warnings):
// one table row per input-view count K, every metric of PROTOCOL.md beside its baselines.
std::string evalResultsPage(const nlohmann::ordered_json& result, const std::string& device,
                            const std::vector<std::string>& warnings);

// Writes dir/index.html (indexPage).
void writeIndexPage(const std::string& dir, const IndexPageInputs& in);

}  // namespace spar::cli
