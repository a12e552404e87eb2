#include "tools/spar/render_command.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <set>

#include "formats/camera_files.h"
#include "formats/cameras.h"
#include "imaging/image_prep.h"
#include "imaging/video_frames.h"
#include "spar/cameras.h"
#include "spar/session.h"
#include "tools/common/errors.h"
#include "tools/spar/index_page.h"
#include "tools/spar/kernel_report.h"
#include "tools/spar/progress.h"
#include "tools/spar/render_outputs.h"
#include "tools/spar/staged_dir.h"
#include "tools/spar/target_scores.h"
#include "tools/spar/warnings.h"

namespace spar::cli {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using ojson = nlohmann::ordered_json;
constexpr size_t kRenderChunk = 8;  // views per render call for --path / --cameras
constexpr int kPathFps = 8;          // frames a second of path.mp4 / path.gif

double msSince(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }

// Everything checked before any device work: the command line, then the files it names.
struct Validated {
  PlannedViews views;
  std::string outDir;
  std::shared_ptr<const Model> model;
  int height = 0, width = 0;  // the size rendered: --size, else the model's
  std::vector<float> images;  // [V, 3, H, W]
  std::vector<CameraD> cameras;  // --cameras
  std::vector<std::string> labels;  // --labels, parsed
  AnimationChoice animation;        // --path: path.mp4 or path.gif
  double loadModelMs = 0, prepareMs = 0;
};

// --labels as the reference parses them: comma-separated, stripped, empty items dropped, no repeats.
std::vector<std::string> parseLabels(const std::string& text) {
  std::vector<std::string> labels;
  std::string item;
  auto flush = [&]() {
    const size_t b = item.find_first_not_of(" \t"), e = item.find_last_not_of(" \t");
    if (b != std::string::npos) {
      const std::string label = item.substr(b, e - b + 1);
      if (std::find(labels.begin(), labels.end(), label) != labels.end())
        throw UsageError("--labels repeats a prompt: " + label);
      labels.push_back(label);
    }
    item.clear();
  };
  for (char ch : text) {
    if (ch == ',') flush();
    else item += ch;
  }
  flush();
  if (labels.empty()) throw UsageError("--labels needs at least one prompt");
  return labels;
}

void needViewsToRender(const RenderArgs& a, const PlannedViews& views) {
  if ((a.labels || a.features) && views.targets.empty() && !a.path && a.cameras.empty())
    throw UsageError("--labels / --features need views to render (target views, --path or --cameras)");
}

// Files and directories (exit 1), cheapest first: nothing is loaded before all exist.
void checkFilesExist(const RenderArgs& a, const PlannedViews& views) {
  std::error_code ec;
  for (const auto& f : views.files) {
    if (!fs::exists(f, ec)) throw Error("image not found: " + f);
    if (fs::is_directory(f, ec)) throw Error("cannot read image " + f + ": it is a directory");
  }
  if (!a.views.video.empty() && !fs::exists(a.views.video, ec)) throw Error("video not found: " + a.views.video);
  if (!a.cameras.empty() && !fs::exists(a.cameras)) throw Error("cameras file not found: " + a.cameras);
  if (!fs::exists(a.model)) throw Error("model not found: " + a.model);
}

// The model (the one `shared` holds when it is the same file), and what it says of the
// request before any image is read: the size, refinement, the semantic branch, the prompts.
void openModel(const RenderArgs& a, RenderContext* shared, Validated& v) {
  const auto t = Clock::now();
  if (shared && shared->model && shared->model->path() == a.model) {
    v.model = shared->model;
  } else {
    v.model = std::make_shared<const Model>(Model::open(a.model));
    if (shared) shared->model = v.model;
  }
  v.loadModelMs = msSince(t);
  const Model& m = *v.model;
  // A --size this model cannot run at is a command line that cannot mean anything for it (exit 2).
  if (a.height) {
    if (const std::string problem = m.sizeProblem(a.height, a.width); !problem.empty())
      throw UsageError("--size: " + problem);
  }
  v.height = int(a.height ? a.height : m.imageHeight());
  v.width = int(a.width ? a.width : m.imageWidth());
  if (const std::string problem = a.refine || a.maskSource == "refined" ? m.refinementProblem() : ""; !problem.empty())
    throw Error(problem + ": --refine / --mask-source refined are not available");
  if ((a.labels || a.features) && !m.semantic())
    throw Error("this model has no semantic branch (use_lseg / semantic loss weight): --labels / --features are "
                "not available");
  if (a.labels) warnAboutPrompts(m.promptWarnings(v.labels), v.labels.size());
}

// The frames of a video: probed, taken at their times, turned and brought to the model's size
// by ffmpeg; then planned as --frames would be.
void loadVideo(const RenderArgs& a, Validated& v) {
  const Model& m = *v.model;
  const VideoInfo info = probeVideo(a.views.video);
  const int64_t frames = a.views.videoFrames ? a.views.videoFrames : (m.trainingViews() ? m.trainingViews() : 4);
  const std::vector<double> times =
      a.views.videoAt.empty() ? spreadTimes(info, int(frames)) : parseVideoTimes(a.views.videoAt);
  std::vector<std::string> names;
  for (double s : times) {
    char at[32];
    std::snprintf(at, sizeof at, "@%.3fs", s);
    names.push_back(a.views.video + at);
  }
  v.views = planVideoViews(a.views, names, m.trainingInputViews() ? m.trainingInputViews() : 2);
  needViewsToRender(a, v.views);
  warnIfTiny(a.views.video, info.width, info.height, v.width, v.height);
  for (const RgbImage& frame : readVideoFrames(a.views.video, info, times, v.height, v.width)) {
    const std::vector<float> img = prepareImage(frame, v.height, v.width);
    v.images.insert(v.images.end(), img.begin(), img.end());
  }
}

void loadImages(Validated& v) {
  for (const auto& f : v.views.files) {
    const RgbImage rgb = loadImageRGB(f);
    warnIfTiny(f, rgb.width, rgb.height, v.width, v.height);
    const std::vector<float> img = prepareImage(rgb, v.height, v.width);
    v.images.insert(v.images.end(), img.begin(), img.end());
  }
}

// --cameras, refused here before any device work with the frame named (the engine checks again).
void loadCameras(const RenderArgs& a, Validated& v) {
  std::string warning;
  v.cameras = readCameraFile(a.cameras, v.width, v.height, &warning);
  if (!warning.empty()) warn(warning);
  if (const std::string p = renderCamerasProblem(toRenderCameras(v.cameras)); !p.empty())
    throw Error(a.cameras + ": " + p);
}

Validated validate(const RenderArgs& a, RenderContext* shared) {
  Validated v;
  // 1. The command line alone (exit 2).
  if (a.model.empty()) throw UsageError("--model is required");
  v.views = planViews(a.views);
  if (a.path && *a.path < 1) throw UsageError("--path needs at least 1 frame, got " + std::to_string(*a.path));
  if (a.path && !a.cameras.empty()) throw UsageError("--cameras and --path exclude each other");
  if (a.out.empty()) throw UsageError("--out is required");
  if (a.labels) v.labels = parseLabels(*a.labels);
  if (a.scores && !a.labels) throw UsageError("--scores needs --labels");
  if (a.views.video.empty()) needViewsToRender(a, v.views);  // a video's plan is known once its frames are
  // 2. Files (exit 1), then the model, then the frames and cameras.
  checkFilesExist(a, v.views);
  v.outDir = checkOutDir(a.out);
  if (a.path && *a.path > 1) v.animation = chooseAnimation(a.animation);
  openModel(a, shared, v);
  const auto t = Clock::now();
  if (!a.views.video.empty()) loadVideo(a, v);
  warnIfManyViews(v.model->trainingViews(), v.views.files.size(), v.views.inputs.size());
  if (a.views.video.empty()) loadImages(v);
  if (!a.cameras.empty()) loadCameras(a, v);
  v.prepareMs = msSince(t);
  return v;
}

// A demonstration model says so, once a process for each model file (a --jobs run renders many
// requests with one), before the work: its renders show what the model is, not the engine.
void noteModelCard(const Model& model) {
  static std::set<std::string> said;
  if (const std::string note = model.demonstrationNote(); !note.empty() && said.insert(model.path()).second)
    std::fprintf(stderr, "spar: note: %s\n", note.c_str());
}

// report.json's "refine": null unless refinement ran; else the mask source and, per refined
// view, its sequence position, whether it was skipped (too few or too many dynamic pixels),
// the dynamic pixels, SAM2's three IoU predictions and the mask chosen.
ojson refineReport(const Encoded& enc, const std::string& maskSource, bool ran) {
  if (!ran) return nullptr;
  ojson views = ojson::array();
  for (const RefinedView& r : enc.refineViews) {
    ojson j = {{"view", r.view}, {"skipped", r.skipped}, {"dynamic_pixels", r.dynamicPixels}};
    if (!r.skipped) {
      j["iou"] = {r.iou[0], r.iou[1], r.iou[2]};
      j["chosen"] = r.chosen;
    }
    views.push_back(j);
  }
  return {{"mask_source", maskSource}, {"views", views}};
}

std::string viewsText(const PlannedViews& p) {
  return std::to_string(p.files.size()) + " views (" + std::to_string(p.inputs.size()) + " inputs, " +
         std::to_string(p.targets.size()) + " targets)";
}

// The device: the one `shared` holds, else a new one (kept in `shared`, else in `own`).
Context& openContext(const RenderArgs& a, RenderContext* shared, std::unique_ptr<Context>& own, Progress& progress) {
  if (shared && shared->context) return *shared->context;
  progress.step("opening the Vulkan device");
  EngineOptions eo;
  eo.device = a.device;
  eo.pipelineCacheFile = pipelineCachePath();
  std::unique_ptr<Context>& keep = shared ? shared->context : own;
  keep = std::make_unique<Context>(EngineOptions::fromEnvironment(eo));
  return *keep;
}

Request makeRequest(const RenderArgs& a, const Validated& v) {
  Request req;
  req.images = v.images;  // a copy: the input views are written beside the outputs (index.html shows them)
  req.height = v.height;
  req.width = v.width;
  req.plan.views = int64_t(v.views.files.size());
  req.plan.inputs = v.views.inputs;
  req.plan.targets = v.views.targets;
  req.assumeStatic = a.assumeStatic;
  req.semanticFeatures = a.labels.has_value() || a.features;
  req.refine = a.refine;
  req.maskSource = a.maskSource == "refined" ? MaskSource::Refined : MaskSource::Raw;
  return req;
}

// Each render call's outputs, written into the staged directory as they arrive (the host holds
// one chunk of views, however long the path): label maps from its semantic features, the
// features read back, the views and their maps.
struct ChunkWriter {
  const RenderArgs& a;
  const Validated& v;
  Session& session;
  RenderWriter& writer;
  double writeMs = 0;

  void operator()(const std::vector<float>& rgb, int64_t n) {
    std::vector<std::vector<int32_t>> maps;
    std::vector<float> scores, features;
    if (a.features) features = session.features();
    if (a.labels) maps = session.labelMaps(v.labels, nullptr, a.scores ? &scores : nullptr);
    const auto tw = Clock::now();
    RenderedViews views;
    views.count = n;
    views.rgb = rgb.data();
    views.labelMaps = a.labels ? &maps : nullptr;
    views.scores = a.scores ? &scores : nullptr;
    views.features = a.features ? &features : nullptr;
    writer.addViews(views);
    writeMs += msSince(tw);
  }
};

// Renders what the mode asks for, through `write`; the targets' RGB comes back (the views in
// "targets" mode, else a render of its own when the request has targets) for their comparison.
std::vector<float> renderViews(const RenderArgs& a, const std::string& mode, const RenderCameras& cams, Session& session,
                               ChunkWriter& write, Progress& progress) {
  const int64_t count = mode == "targets" ? int64_t(write.v.views.targets.size()) : int64_t(cams.size());
  std::vector<float> targets;
  if (count > 0) {
    const std::string views = count == 1 ? " view" : " views";
    const std::string what = mode == "targets" ? " target" + views
                             : mode == "path"  ? views + " along the input cameras"
                                               : views + " from " + a.cameras;
    const std::string rendering = "rendering " + std::to_string(count) + what;
    progress.step(rendering);
    if (mode == "targets") {
      targets = session.renderTargets();
      write(targets, count);
      return targets;
    }
    // A long path in chunks: device memory for a few views at a time, not for all N.
    for (size_t j0 = 0; j0 < cams.size(); j0 += kRenderChunk) {
      const size_t j1 = std::min(cams.size(), j0 + kRenderChunk);
      if (j0 > 0) progress.step(rendering + " (" + std::to_string(j0) + " written)");
      RenderCameras chunk;
      chunk.c2w.assign(cams.c2w.begin() + j0, cams.c2w.begin() + j1);
      chunk.fxfycxcy.assign(cams.fxfycxcy.begin() + j0, cams.fxfycxcy.begin() + j1);
      write(session.render(chunk), int64_t(j1 - j0));
    }
  }
  if (mode != "targets" && !write.v.views.targets.empty()) {
    progress.step("rendering the " + std::to_string(write.v.views.targets.size()) + " target frames to compare");
    targets = session.renderTargets();
  }
  return targets;
}

ojson stagesJson(const std::vector<StageTime>& times) {
  // gpu_ms: compute only; build_ms: the driver building kernels during the stage (first
  // dispatches on llvmpipe); wall_ms includes both and pipeline creation; dispatches, barriers,
  // submits (host waits), transformer blocks and the most dispatches one took: what it took in commands.
  ojson stages = ojson::array();
  for (const auto& s : times)
    stages.push_back({{"name", s.name}, {"gpu_ms", s.gpuMs}, {"build_ms", s.buildMs}, {"wall_ms", s.wallMs},
                      {"device_bytes_after", s.deviceBytesAfter}, {"device_peak_bytes", s.devicePeakBytes},
                      {"dispatches", s.dispatches}, {"barriers", s.barriers}, {"submits", s.submits},
                      {"transformer_blocks", s.transformerBlocks}, {"block_dispatches", s.blockDispatches}});
  return stages;
}

// device memory at its peak, the estimate, and how many buffers and submissions it took (the
// counts EngineOptions::faults numbers: tests/test_spar_faults.cpp)
ojson memoryJson(const MemoryStats& m, const MemoryEstimate& need) {
  return {{"peak_bytes", m.peakBytes},
          {"estimated_min_bytes", need.minBytes},       // spar/memory.h: the lower bound
          {"estimated_max_bytes", need.maxBytes},       // and the upper bound
          {"estimated_weight_bytes", need.weightBytes},  // of which weights (as weights_bytes_loaded)
          {"budget_bytes", need.budgetBytes},
          {"max_input_views", need.maxInputViews},  // this many input views surely fit budget_bytes at this size
          {"allocations", m.allocations},
          {"submissions", m.submissions}};
}

struct RunFacts {
  std::string mode;
  std::string animationFile, animationHow;  // the --path animation written, and how
  int64_t rendered = 0;
  double totalSeconds = 0;
  MemoryEstimate need;
  ojson host, targets;
};

ojson reportJson(const RenderArgs& a, const Validated& v, const Encoded& enc, Context& context, Session& session,
                 const RunFacts& f) {
  ojson report = {
      {"tool", "spar"},
      {"command", "render"},
      {"model", absolutePath(a.model)},
      {"device", context.deviceName()},
      {"precision", a.precision},
      {"views",
       {{"total", v.views.files.size()},
        {"inputs", v.views.inputs.size()},
        {"targets", v.views.targets.size()},
        {"rendered", f.rendered}}},
      {"render", f.mode},
      // the size the views were prepared and rendered at, and whether --size chose it
      {"image_size", {{"height", v.height}, {"width", v.width}, {"from", a.height ? "--size" : "model"}}},
      {"assume_static", a.assumeStatic},
      // SAM2.1 refinement (only when asked): which masks gated the tokens, and per input view
      // what SAM2 decided (refined_XX.png beside mask_XX.png)
      {"refine", refineReport(enc, a.maskSource, a.refine || a.maskSource == "refined")},
      // from the start of the command to here: everything but writing this file
      {"total_seconds", f.totalSeconds},
      {"stages", stagesJson(session.stageTimes())},  // GPU stages that ran, label maps included
      {"host_stages", f.host},                        // CPU-side phases of the command
      {"kernels", kernelReportJson(context.kernelReport())},  // pipelines: creation, driver builds, compute
      {"device_memory", memoryJson(context.memory(), f.need)},
      {"weights_bytes_loaded", session.weightBytesLoaded()},
      // each target frame's render against the frame (whole image), beside copying the nearest input
      {"targets", f.targets},
  };
  // what the model file says it is (a demonstration model's card): the page opens with it
  if (const auto note = v.model->demonstration()) report["model_note"] = note->claim;
  // --path: which animation was written, and how (path.mp4 through ffmpeg, or path.gif and why)
  if (!f.animationFile.empty()) report["animation"] = {{"file", f.animationFile}, {"how", f.animationHow}};
  return report;
}

}  // namespace

void runRender(const RenderArgs& a, RenderContext* shared) {
  takeWarnings();  // this render's page lists this render's warnings only
  const auto start = Clock::now();
  Validated v = validate(a, shared);
  noteModelCard(*v.model);
  const int h = v.height, w = v.width;
  RunFacts f;
  f.mode = !a.cameras.empty() ? "cameras" : (a.path ? "path" : "targets");
  f.host = ojson::array({{{"name", "load_model"}, {"wall_ms", v.loadModelMs}},
                         {{"name", "prepare_images"}, {"wall_ms", v.prepareMs}}});
  Progress progress;
  std::unique_ptr<Context> own;  // outlives the session below
  try {
    auto t = Clock::now();
    Context& context = openContext(a, shared, own, progress);
    f.host.push_back({{"name", "device"}, {"wall_ms", msSince(t)}});
    SessionOptions so;
    so.precision = parsePrecision(a.precision);
    Session session(context, *v.model, so);
    const Request req = makeRequest(a, v);

    // A request that cannot fit the device is refused here, before any work, with its need.
    const int64_t planned = !a.cameras.empty() ? int64_t(v.cameras.size()) : (a.path ? *a.path : 0);
    RenderUse use;
    use.viewsPerCall = std::max<int64_t>(std::min<int64_t>(planned, kRenderChunk), int64_t(v.views.targets.size()));
    use.labelPrompts = int64_t(v.labels.size());
    f.need = session.estimateMemory(req, use);
    if (!f.need.refusal.empty()) throw Error(f.need.refusal + ": fewer views, a smaller --size or --precision fp16");
    if (!f.need.warning.empty()) warn(f.need.warning + " (fewer views or a smaller --size fit)");

    progress.step("encoding " + viewsText(v.views) + " at " + std::to_string(h) + "x" + std::to_string(w) + " (HxW) on " +
                  context.deviceName() + (a.assumeStatic ? " (assume static)" : ""));
    const Encoded& enc = session.encode(req);
    // --labels: the prompts through CLIP's text encoder on the device, once; its weights are
    // loaded only now, for this request.
    if (a.labels) {
      progress.step("encoding " + std::to_string(v.labels.size()) + " label prompts");
      session.preparePrompts(v.labels);
    }
    RenderCameras renderCams;
    if (f.mode == "path") renderCams = pathCameras(enc, v.views.inputs, *a.path);
    if (f.mode == "cameras") renderCams = toRenderCameras(v.cameras);
    f.rendered = f.mode == "targets" ? int64_t(v.views.targets.size()) : int64_t(renderCams.size());

    StagedDir staged(v.outDir);
    RenderLayout layout;
    layout.viewFormat = a.format;
    layout.width = w;
    layout.height = h;
    layout.labels = v.labels;
    layout.featureChannels = v.model->featureChannels();
    // A --path is a smooth camera move: also written as path.mp4 / path.gif (views beside label maps).
    if (f.mode == "path" && f.rendered > 1) {
      layout.animationFps = kPathFps;
      layout.animation = v.animation;
    }
    RenderWriter writer(staged.path(), layout);
    ChunkWriter chunks{a, v, session, writer};
    const std::vector<float> targetRgb = renderViews(a, f.mode, renderCams, session, chunks, progress);

    CamerasDocument cd;
    cd.width = w;
    cd.height = h;
    cd.files = v.views.files;
    cd.inputs = v.views.inputs;
    cd.targets = v.views.targets;
    cd.canonicalIndex = enc.canonicalIndex;
    for (size_t i = 0; i < v.views.files.size(); ++i) cd.cameras.push_back(estimatedCamera(enc, int64_t(i)));
    cd.render = f.mode;
    if (f.mode != "targets") cd.renderCameras = fromRenderCameras(renderCams);

    progress.step("writing " + v.outDir);
    t = Clock::now();
    // The prepared input views (what the model saw), for the page's inputs with their masks.
    const size_t plane = size_t(3) * size_t(h) * size_t(w);
    for (size_t k = 0; k < v.views.inputs.size(); ++k) {
      char name[32];
      std::snprintf(name, sizeof name, "input_%02zu.png", k);
      writePng((fs::path(staged.path()) / name).string(), v.images.data() + size_t(v.views.inputs[k]) * plane, 3, h, w);
    }
    // The targets against their frames, and the files the page shows them with.
    f.targets = writeTargetScores(staged.path(), targetRgb, v.images, v.views.inputs, v.views.targets, h, w);
    const std::vector<float> noMotion;
    writer.finish(a.assumeStatic ? noMotion : enc.motionInput, a.assumeStatic ? 0 : int64_t(v.views.inputs.size()),
                  v.model->maskThreshold(), cd);
    if (!enc.refinedInput.empty()) writer.writeRefined(enc.refinedInput, int64_t(v.views.inputs.size()));
    int written = writer.files() + int(v.views.inputs.size()) + targetFileCount(v.views.targets.size());
    f.host.push_back({{"name", "write_outputs"}, {"wall_ms", chunks.writeMs + msSince(t)}});

    f.animationFile = writer.animationFile();
    f.animationHow = writer.animationDescription();
    f.totalSeconds = msSince(start) / 1000.0;
    const ojson report = reportJson(a, v, enc, context, session, f);
    writeJson((fs::path(staged.path()) / "report.json").string(), report);
    ++written;
    // Last: the page that shows it all (index_page.h), with the warnings of this render.
    writeIndexPage(staged.path(), {report, camerasJson(cd), takeWarnings(), v.model->demonstration()});
    ++written;
    staged.commit();
    char done[64];
    std::snprintf(done, sizeof(done), " in %.2f s", msSince(start) / 1000.0);
    progress.step("wrote " + std::to_string(written) + " files to " + v.outDir + done +
                  (writer.animationFile().empty()
                       ? ""
                       : " (" + writer.animationFile() + ": " + writer.animationDescription() + ")"));
    progress.finish();
  } catch (...) {
    progress.finish();
    throw;
  }
}

}  // namespace spar::cli
