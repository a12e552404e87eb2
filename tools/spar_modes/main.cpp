// spar-modes: every precision and shortcut the engine offers, on one model and one set of
// inputs, side by side: wall and GPU time per stage and in total, weight bytes, device memory,
// and error against the PyTorch fp32 reference on the same inputs (engineering.md "Report
// error against run time"). A model packed with SAM2.1 adds the refine modes (the refined
// masks against the reference's refinement; with -refined they gate the tokens).
//
//   spar-modes [--model M.spar --checkpoint X.pt [--config C] --frames f0 f1 .. --inputs 0,2]
//              [--modes fp32,fp16,fp32-static,fp16-static,fp32-refine,...] [--sam2 SAM2.pt [--sam2-config C]]
//              [--repeat N] [--out DIR] [--device D] [--labels "a,b,..."]
//
// --labels (semantic models): the targets' label maps in every mode, against the reference's.
// Without --model: the tiny photometric model of the test fixture (build/tests/spar_goldens,
// made by `ctest -R make_spar_goldens`), frames 0..4 with inputs 0,2,4. Writes DIR/modes.md
// (also on stdout), DIR/modes.json and DIR/modes.svg (RGB PSNR against wall time); the
// reference's goldens stay in DIR/reference* and are reused while their inputs are unchanged.
// Exit codes: 0 done, 1 something wrong on the way, 2 a command line that cannot mean anything.
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "spar/error.h"
#include "spar/images.h"
#include "spar/model.h"
#include "tools/spar_modes/accuracy.h"
#include "tools/spar_modes/modes.h"
#include "tools/spar_modes/reference.h"
#include "tools/spar_modes/report.h"
#include "tools/spar_modes/svg_plot.h"

namespace {

namespace fs = std::filesystem;
using namespace spar;
using namespace spar::modes;

struct Args {
  std::string model, checkpoint, config, inputs, modes, out = "spar-modes-out", device, sam2, sam2Config, labels;
  std::vector<std::string> frames;
  int repeat = 3;
};

struct UsageError : Error {
  using Error::Error;
};

// The test fixture's tiny model and frames, when no --model is given.
void useFixture(Args& a) {
  if (!a.checkpoint.empty() || !a.frames.empty() || !a.inputs.empty() || !a.config.empty())
    throw UsageError("--checkpoint, --config, --frames and --inputs go with --model");
  const std::string dir = SPAR_MODES_FIXTURE;
  if (!fs::exists(dir + "/tiny.spar"))
    throw Error(dir + "/tiny.spar not found: run `ctest --test-dir <build> -R make_spar_goldens` or give --model");
  a.model = dir + "/tiny.spar";
  a.checkpoint = dir + "/tiny.pt";
  a.config = dir + "/tiny_photometric.json";
  for (int i = 0; i < 5; ++i) a.frames.push_back(dir + "/frame_" + std::to_string(i) + ".png");
  a.inputs = "0,2,4";
}

std::vector<int64_t> parseInputs(const std::string& text, size_t frames) {
  std::vector<int64_t> out;
  std::stringstream ss(text);
  for (std::string item; std::getline(ss, item, ',');) {
    try {
      size_t used = 0;
      const long v = std::stol(item, &used);
      if (used != item.size()) throw std::invalid_argument(item);
      out.push_back(v);
    } catch (const std::logic_error&) {
      throw UsageError("--inputs must be comma-separated frame positions, got '" + text + "'");
    }
  }
  for (int64_t v : out)
    if (v < 0 || size_t(v) >= frames) throw UsageError("--inputs position " + std::to_string(v) + " is outside the " +
                                                       std::to_string(frames) + " frames");
  return out;
}

void writeFile(const fs::path& path, const std::string& text) {
  const fs::path tmp = path.string() + ".tmp";
  {
    std::ofstream f(tmp);
    f << text;
    if (!f) throw Error(path.string() + ": cannot write");
  }
  fs::rename(tmp, path);
}

int run(Args a) {
  if (a.model.empty()) useFixture(a);
  if (a.checkpoint.empty() || a.frames.empty() || a.inputs.empty())
    throw UsageError("--model needs --checkpoint (the reference's), --frames and --inputs");
  if (a.repeat < 1) throw UsageError("--repeat must be at least 1");
  const Model model = Model::open(a.model);
  const bool sam2 = model.refinementProblem().empty();
  std::vector<Mode> modes;
  try {
    modes = selectModes(a.modes, sam2);
  } catch (const Error& e) {
    throw UsageError(e.what());
  }
  const bool anyRefine = std::any_of(modes.begin(), modes.end(), [](const Mode& m) { return m.refine; });
  const bool anyRefinedGating = std::any_of(modes.begin(), modes.end(), [](const Mode& m) { return m.refinedGating; });
  if (anyRefine && a.sam2.empty())
    throw UsageError("the refine modes need --sam2 (the SAM2.1 checkpoint the model was packed with, for the "
                     "reference; or leave them out with --modes)");
  const int64_t h = model.imageHeight(), w = model.imageWidth();
  Request request;
  request.plan.views = int64_t(a.frames.size());
  request.plan.inputs = parseInputs(a.inputs, a.frames.size());
  std::sort(request.plan.inputs.begin(), request.plan.inputs.end());
  for (int64_t v = 0; v < request.plan.views; ++v)
    if (!std::binary_search(request.plan.inputs.begin(), request.plan.inputs.end(), v)) request.plan.targets.push_back(v);
  request.plan.validate();
  if (request.plan.targets.empty()) throw UsageError("no target frames: RGB error needs at least one target");
  for (const std::string& f : a.frames) {
    const std::vector<float> img = loadImage(f, int(h), int(w));
    request.images.insert(request.images.end(), img.begin(), img.end());
  }

  // Prompts: the targets' label maps in every mode, against the reference's (CLIP's tokenizer
  // packed in the model; the reference reads the repository's copy of the same BPE table).
  std::vector<std::string> labelNames;
  if (!a.labels.empty()) {
    std::stringstream ss(a.labels);
    for (std::string item; std::getline(ss, item, ',');) labelNames.push_back(item);
    if (!model.semantic()) throw UsageError("--labels needs a model with the semantic branch");
    model.promptWarnings(labelNames);  // a model without CLIP's tokenizer is refused before any work
  }

  const fs::path out = fs::absolute(a.out);
  fs::create_directories(out);
  const ReferenceInputs refIn{SPAR_PYTHON, SPAR_SOURCE_DIR,     a.checkpoint, a.config, a.frames,
                              request.plan.inputs, a.sam2, a.sam2Config, a.labels, SPAR_CLIP_BPE};
  const bool anyStatic = std::any_of(modes.begin(), modes.end(), [](const Mode& m) { return m.assumeStatic; });
  std::vector<std::pair<ReferenceRun, std::string>> runs = {{ReferenceRun::Whole, (out / "reference").string()}};
  if (anyStatic) runs.emplace_back(ReferenceRun::Static, (out / "reference_static").string());
  // The refined masks: from the refined-gating run when there is one (it refines the same way),
  // else from a --refine run.
  if (anyRefinedGating) runs.emplace_back(ReferenceRun::RefinedGating, (out / "reference_refined").string());
  else if (anyRefine) runs.emplace_back(ReferenceRun::Refine, (out / "reference_refine").string());
  const std::vector<Reference> refs = loadReferences(refIn, runs);
  const Reference& ref = refs[0];
  const Reference refStatic = anyStatic ? refs[1] : Reference{};
  const Reference refRefine = anyRefine ? refs.back() : Reference{};

  EngineOptions engineOptions;
  engineOptions.device = a.device;
  engineOptions = EngineOptions::fromEnvironment(engineOptions);
  std::vector<ModeResult> results;
  std::string deviceName;
  for (const Mode& m : modes) {
    std::fprintf(stderr, "spar-modes: %s ...\n", m.name.c_str());
    ModeResult r;
    r.run = runMode(engineOptions, model, request, m, a.repeat, labelNames);
    deviceName = r.run.device;
    r.vsReference = rgbError(r.run.rgb, ref.rgb);
    r.maskAgreement = maskAgreement(r.run.motion, ref.mask, model.maskThreshold());
    r.motionMaxAbs = motionMaxAbs(r.run.motion, ref.motion);
    if (m.refine) r.refinedAgreement = maskAgreement(r.run.refined, refRefine.refined, 0.5);
    r.labelAgreement = labelAgreement(r.run.labels, ref.labels);
    r.vsSameMode = rgbError(r.run.rgb, m.assumeStatic ? refStatic.rgb : m.refinedGating ? refRefine.rgb : ref.rgb);
    results.push_back(std::move(r));
  }

  ReportSetup setup;
  setup.model = fs::absolute(a.model).string();
  setup.device = deviceName;
  setup.modelFileBytes = model.fileBytes();
  setup.fileWeights = model.matrixStorage();
  setup.frames = a.frames;
  setup.inputs = request.plan.inputs;
  setup.targets = request.plan.targets;
  setup.height = h;
  setup.width = w;
  setup.reference = ref.dir;
  setup.referenceStatic = refStatic.dir;
  setup.referenceMs = ref.modelMs;
  setup.referenceStaticMs = refStatic.modelMs;
  setup.referenceRefine = refRefine.dir;
  setup.referenceRefineMs = refRefine.modelMs;
  setup.labels = labelNames;

  const std::string markdown = reportMarkdown(setup, results);
  std::vector<PlotPoint> points;
  for (const ModeResult& r : results) points.push_back({r.run.mode.name, r.run.wallMs, r.vsReference.psnrDb});
  writeFile(out / "modes.md", markdown);
  writeFile(out / "modes.json", reportJson(setup, results).dump(1) + "\n");
  writeFile(out / "modes.svg", scatterSvg("SPAR modes on " + deviceName + ": error against run time",
                                          "wall time per run (ms, encode + render)",
                                          "RGB PSNR vs PyTorch fp32 (dB)", points));
  std::fputs(markdown.c_str(), stdout);
  std::fprintf(stderr, "spar-modes: wrote %s/modes.{md,json,svg}\n", out.string().c_str());
  return 0;
}

int fail(std::string message, int code) {
  for (char& c : message)
    if (c == '\n' || c == '\r') c = ' ';
  std::fprintf(stderr, "spar-modes: error: %s\n", message.c_str());
  return code;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"spar-modes: every precision / shortcut of the engine side by side (time, memory, error against "
               "the PyTorch fp32 reference)"};
  Args a;
  app.add_option("--model", a.model, "packed model (.spar); default: the test fixture's tiny model");
  app.add_option("--checkpoint", a.checkpoint, "the checkpoint the model was packed from (for spar-reference)");
  app.add_option("--config", a.config, "spar-reference --config (tiny|full|PATH; default: inferred)");
  app.add_option("--frames", a.frames, "all frames in capture order");
  app.add_option("--inputs", a.inputs, "positions of the input frames, e.g. 0,2 (the rest are targets)");
  std::string modeNames;
  for (const Mode& m : allModes()) modeNames += (modeNames.empty() ? "" : ",") + m.name;
  app.add_option("--modes", a.modes,
                 "comma-separated subset of " + modeNames + " (default: all; the refine modes when the model has SAM2.1)");
  app.add_option("--sam2", a.sam2, "the SAM2.1 checkpoint the model was packed with (the reference's, refine modes)");
  app.add_option("--sam2-config", a.sam2Config, "its variant for the reference (NAME|YAML|JSON; default: inferred)");
  app.add_option("--labels", a.labels,
                 "comma-separated prompts (semantic models): the targets' label maps in every mode, against the "
                 "reference's");
  app.add_option("--repeat", a.repeat, "measured runs per mode after the first (median reported; default 3)");
  app.add_option("--out", a.out, "directory for modes.md, modes.json, modes.svg and the reference's goldens");
  app.add_option("--device", a.device, "Vulkan device index or part of its name (default: SPAR_DEVICE, else the "
                                       "first GPU)");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() == 0) return app.exit(e);
    return fail(std::string(e.what()) + " (see --help)", 2);
  }
  try {
    return run(a);
  } catch (const UsageError& e) {
    return fail(std::string(e.what()) + " (see --help)", 2);
  } catch (const std::exception& e) {
    return fail(e.what(), 1);
  }
}
