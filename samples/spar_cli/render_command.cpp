#include "samples/spar_cli/render_command.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <set>

#include "engine/engine.h"
#include "engine/memory.h"
#include "engine/ops/im2col.h"
#include "engine/recorder.h"
#include "formats/cameras.h"
#include "formats/camera_files.h"
#include "imaging/image_prep.h"
#include "imaging/video_frames.h"
#include "model/camera_checks.h"
#include "model/memory_estimate.h"
#include "model/packed_model.h"
#include "model/spar_config.h"
#include "model/spar_pipeline.h"
#include "samples/spar_cli/errors.h"
#include "samples/spar_cli/index_page.h"
#include "samples/spar_cli/kernel_report.h"
#include "text/prompt_labels.h"
#include "samples/spar_cli/progress.h"
#include "samples/spar_cli/render_outputs.h"
#include "samples/spar_cli/staged_dir.h"
#include "samples/spar_cli/warnings.h"
#include "model/weight_set.h"

namespace spar::cli {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
constexpr size_t kRenderChunk = 8;  // views per render call for --path / --cameras
constexpr int kPathFps = 8;          // frames a second of path.mp4 / path.gif

double msSince(Clock::time_point t) { return std::chrono::duration<double, std::milli>(Clock::now() - t).count(); }

// Everything checked before any device work: the command line, then the files it names.
struct Validated {
  PlannedViews views;
  std::string outDir;
  std::shared_ptr<const PackedModel> model;
  SparConfig config;
  int height = 0, width = 0;  // the size rendered: --size, else the model's
  std::vector<float> images;  // [V, 3, H, W]
  std::vector<CameraD> cameras;  // --cameras
  std::vector<std::string> labels;  // --labels, parsed
  std::vector<int32_t> labelIds;    // their CLIP token ids [P, 77]
  AnimationChoice animation;        // --path: path.mp4 or path.gif
  double loadModelMs = 0, prepareMs = 0;
};

Validated validate(const RenderArgs& a, RenderContext* shared) {
  Validated v;
  // 1. The command line alone (exit 2).
  if (a.model.empty()) throw UsageError("--model is required");
  v.views = planViews(a.views);
  if (a.path && *a.path < 1) throw UsageError("--path needs at least 1 frame, got " + std::to_string(*a.path));
  if (a.path && !a.cameras.empty()) throw UsageError("--cameras and --path exclude each other");
  if (a.out.empty()) throw UsageError("--out is required");
  if (a.labels) {
    // As the reference parses them: comma-separated, stripped, empty items dropped, no repeats.
    std::string item;
    auto flush = [&]() {
      const size_t b = item.find_first_not_of(" \t"), e = item.find_last_not_of(" \t");
      if (b != std::string::npos) {
        const std::string label = item.substr(b, e - b + 1);
        if (std::find(v.labels.begin(), v.labels.end(), label) != v.labels.end())
          throw UsageError("--labels repeats a prompt: " + label);
        v.labels.push_back(label);
      }
      item.clear();
    };
    for (char ch : *a.labels) {
      if (ch == ',') flush();
      else item += ch;
    }
    flush();
    if (v.labels.empty()) throw UsageError("--labels needs at least one prompt");
  }
  if (a.scores && !a.labels) throw UsageError("--scores needs --labels");
  auto needViewsToRender = [&]() {
    if ((a.labels || a.features) && v.views.targets.empty() && !a.path && a.cameras.empty())
      throw UsageError("--labels / --features need views to render (target views, --path or --cameras)");
  };
  if (a.views.video.empty()) needViewsToRender();  // a video's plan is known once its frames are

  // 2. Files and directories (exit 1), cheapest first: nothing is loaded before all exist.
  for (const auto& f : v.views.files) {
    std::error_code ec;
    if (!fs::exists(f, ec)) throw Error("image not found: " + f);
    if (fs::is_directory(f, ec)) throw Error("cannot read image " + f + ": it is a directory");
  }
  if (!a.views.video.empty()) {
    std::error_code ec;
    if (!fs::exists(a.views.video, ec)) throw Error("video not found: " + a.views.video);
  }
  if (!a.cameras.empty() && !fs::exists(a.cameras)) throw Error("cameras file not found: " + a.cameras);
  if (!fs::exists(a.model)) throw Error("model not found: " + a.model);
  v.outDir = checkOutDir(a.out);
  if (a.path && *a.path > 1) v.animation = chooseAnimation(a.animation);

  auto t = Clock::now();
  if (shared && shared->model && shared->model->path() == a.model) {
    v.model = shared->model;
  } else {
    v.model = std::make_shared<const PackedModel>(PackedModel::open(a.model));
    if (shared) shared->model = v.model;
  }
  v.config = SparConfig::fromJson(v.model->config(), v.model->path());
  v.loadModelMs = msSince(t);
  // A --size this model cannot run at is a command line that cannot mean anything for it
  // (exit 2); known only now that the model is open, still before any image is read.
  if (a.height) {
    if (const std::string problem = imageSizeProblem(v.config, a.height, a.width); !problem.empty())
      throw UsageError("--size: " + problem);
  }
  v.height = int(a.height ? a.height : v.config.imageHeight);
  v.width = int(a.width ? a.width : v.config.imageWidth);
  if (const std::string problem = a.refine || a.maskSource == "refined" ? refinementProblem(*v.model) : "";
      !problem.empty())
    throw Error(problem + ": --refine / --mask-source refined are not available");
  if (a.labels || a.features) {
    if (!v.config.semanticDecoding())
      throw Error("this model has no semantic branch (use_lseg / semantic loss weight): --labels / --features are "
                  "not available");
  }
  if (a.labels) {
    const TokenizedPrompts tokenized = tokenizePrompts(*v.model, v.labels);
    warnAboutPrompts(tokenized, v.labels.size());
    v.labelIds = tokenized.ids;
  }

  t = Clock::now();
  const int h = v.height, w = v.width;
  if (!a.views.video.empty()) {
    // The frames of a video: probed, taken at their times, turned and brought to the model's
    // size by ffmpeg; then planned as --frames would be.
    const VideoInfo info = probeVideo(a.views.video);
    const int64_t frames = a.views.videoFrames ? a.views.videoFrames : v.config.raw.value("num_views", int64_t(4));
    const std::vector<double> times =
        a.views.videoAt.empty() ? spreadTimes(info, int(frames)) : parseVideoTimes(a.views.videoAt);
    std::vector<std::string> names;
    for (double s : times) {
      char at[32];
      std::snprintf(at, sizeof at, "@%.3fs", s);
      names.push_back(a.views.video + at);
    }
    v.views = planVideoViews(a.views, names, v.config.raw.value("num_input_views", int64_t(2)));
    needViewsToRender();
    warnIfTiny(a.views.video, info.width, info.height, w, h);
    for (const RgbImage& frame : readVideoFrames(a.views.video, info, times, h, w)) {
      const std::vector<float> img = prepareImage(frame, h, w);
      v.images.insert(v.images.end(), img.begin(), img.end());
    }
  }
  warnIfManyViews(v.config, v.views.files.size(), v.views.inputs.size());
  for (const auto& f : a.views.video.empty() ? v.views.files : std::vector<std::string>{}) {
    const RgbImage rgb = loadImageRGB(f);
    warnIfTiny(f, rgb.width, rgb.height, w, h);
    const std::vector<float> img = prepareImage(rgb, h, w);
    v.images.insert(v.images.end(), img.begin(), img.end());
  }
  if (!a.cameras.empty()) {
    std::string warning;
    v.cameras = readCameraFile(a.cameras, w, h, &warning);
    if (!warning.empty()) warn(warning);
    // Refused here, before any device work, with the frame named (the engine checks again).
    const RenderCameras rc = toRenderCameras(v.cameras);
    for (size_t i = 0; i < rc.size(); ++i)
      if (const std::string p = renderCameraProblem(rc.c2w[i], rc.fxfycxcy[i]); !p.empty())
        throw Error(a.cameras + ": camera " + std::to_string(i) + ": " + p);
  }
  v.prepareMs = msSince(t);
  return v;
}

// A demonstration model says so, once a process for each model file (a --jobs run renders many
// requests with one), before the work: its renders show what the model is, not the engine.
void noteModelCard(const PackedModel& model) {
  static std::set<std::string> said;
  if (const auto& card = model.modelCard(); card && said.insert(model.path()).second)
    std::fprintf(stderr, "spar: note: %s\n", modelCardSentence(*card).c_str());
}

// report.json's "refine": null unless refinement ran; else the mask source and, per refined
// view, its sequence position, whether it was skipped (too few or too many dynamic pixels),
// the dynamic pixels, SAM2's three IoU predictions and the mask chosen.
nlohmann::ordered_json refineReport(const SparEncoded& enc, const std::string& maskSource, bool ran) {
  if (!ran) return nullptr;
  nlohmann::ordered_json views = nlohmann::ordered_json::array();
  for (const RefinedView& r : enc.refineViews) {
    nlohmann::ordered_json j = {{"view", r.view}, {"skipped", r.skipped}, {"dynamic_pixels", r.dynamicPixels}};
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

}  // namespace

RenderContext::RenderContext() = default;
RenderContext::~RenderContext() = default;

void runRender(const RenderArgs& a, RenderContext* shared) {
  takeWarnings();  // this render's page lists this render's warnings only
  const auto start = Clock::now();
  Validated v = validate(a, shared);
  noteModelCard(*v.model);
  const SparConfig& cfg = v.config;
  const int h = v.height, w = v.width;
  const std::string mode = !a.cameras.empty() ? "cameras" : (a.path ? "path" : "targets");

  Progress progress;
  nlohmann::ordered_json host = nlohmann::ordered_json::array();
  host.push_back({{"name", "load_model"}, {"wall_ms", v.loadModelMs}});
  host.push_back({{"name", "prepare_images"}, {"wall_ms", v.prepareMs}});
  try {
    auto t = Clock::now();
    std::unique_ptr<Engine> ownEngine;
    if (!shared || !shared->engine) {
      progress.step("opening the Vulkan device");
      EngineOptions eo;
      eo.device = a.device;
      eo.pipelineCacheFile = pipelineCachePath();
      ownEngine = std::make_unique<Engine>(EngineOptions::fromEnvironment(eo));
    }
    Engine& engine = shared ? *(shared->engine ? shared->engine : (shared->engine = std::move(ownEngine))) : *ownEngine;
    host.push_back({{"name", "device"}, {"wall_ms", msSince(t)}});

    SparPipelineOptions po;
    po.profile = true;
    po.weightType = WeightSet::precisionType(a.precision);

    // A request that cannot fit the device is refused here, before any work, with its need.
    MemoryQuery mq;
    mq.views = int64_t(v.views.files.size());
    mq.inputs = int64_t(v.views.inputs.size());
    mq.targets = int64_t(v.views.targets.size());
    const int64_t planned = !a.cameras.empty() ? int64_t(v.cameras.size()) : (a.path ? *a.path : mq.targets);
    mq.renderChunk = a.path || !a.cameras.empty() ? std::min<int64_t>(planned, kRenderChunk) : mq.targets;
    mq.height = h;
    mq.width = w;
    mq.assumeStatic = a.assumeStatic;
    mq.semantic = a.labels.has_value() || a.features;
    mq.labels = a.labels.has_value();
    mq.prompts = int64_t(v.labels.size());
    mq.refine = a.refine || a.maskSource == "refined";
    mq.matrixType = po.weightType;
    mq.staging = !engine.caps().hostVisibleDeviceLocal;
    mq.im2colScratchBytes = ops::im2colScratchBytes(engine);
    engine.plan();  // a GPU measures its kernel choice now (once), not inside the request
    mq.peakBefore = engine.memory().peakBytes();
    const MemoryNeed need = estimateMemory(*v.model, cfg, mq);
    const uint64_t budget = engine.memory().budget();
    // The most input views this device surely takes at this size: the upper bound grows by
    // about the same amount with each one.
    MemoryQuery more = mq;
    ++more.views;
    ++more.inputs;
    const uint64_t perInput = estimateMemory(*v.model, cfg, more).upperBytes - need.upperBytes;
    const int64_t maxInputs = budget > need.upperBytes
                                  ? mq.inputs + int64_t((budget - need.upperBytes) / std::max<uint64_t>(perInput, 1))
                                  : 0;
    auto mib = [](uint64_t b) { return std::to_string((b + (1 << 20) - 1) >> 20) + " MiB"; };
    if (budget && need.total() > budget) {
      throw Error("this request needs at least " + mib(need.total()) + " of device memory (weights " +
                  mib(need.weightBytes) + ", activations " + mib(need.activationBytes) + " for " + viewsText(v.views) +
                  " at " + std::to_string(h) + "x" + std::to_string(w) + "), more than the " + mib(budget) +
                  " available (" + engine.memory().budgetSource() +
                  "): fewer views, a smaller --size or --precision fp16");
    }
    if (budget && need.upperBytes > budget) {
      warn("this request may need up to " + mib(need.upperBytes) + " of device memory, more than the " + mib(budget) +
           " available (" + engine.memory().budgetSource() + "): it may run out midway (fewer views or a smaller --size fit)");
    }
    SparPipeline pipeline(engine, *v.model, po);
    SparRequest req;
    req.images = v.images;  // a copy: the input views are written beside the outputs (index.html shows them)
    req.height = h;
    req.width = w;
    req.plan.views = int64_t(v.views.files.size());
    req.plan.inputs = v.views.inputs;
    req.plan.targets = v.views.targets;
    req.assumeStatic = a.assumeStatic;
    req.semanticFeatures = a.labels.has_value() || a.features;
    req.refine = a.refine;
    req.maskSource = a.maskSource == "refined" ? MaskSource::Refined : MaskSource::Raw;
    req.plan.validate();

    progress.step("encoding " + viewsText(v.views) + " at " + std::to_string(h) + "x" + std::to_string(w) + " (HxW) on " +
                  engine.caps().name + (a.assumeStatic ? " (assume static)" : ""));
    const SparEncoded& enc = pipeline.encode(req);

    // --labels: the prompts through CLIP's text encoder on the device, once; its weights are
    // loaded only now, for this request.
    PromptEmbeddings text;
    double labelGpuMs = 0, labelWallMs = 0, labelBuildMs = 0;
    uint64_t textBytesAfter = 0, textPeak = 0, labelBytesAfter = 0, labelPeak = 0;  // as the stages report them
    if (a.labels) {
      progress.step("encoding " + std::to_string(v.labels.size()) + " label prompts");
      text = encodePrompts(engine, *v.model, cfg, po.weightType, v.labelIds, int64_t(v.labels.size()));
      textBytesAfter = engine.memory().bytesInUse();
      textPeak = engine.memory().peakBytes();
    }
    RenderCameras renderCams;
    if (mode == "path") renderCams = toRenderCameras(inputCameraPath(enc, v.views.inputs, *a.path));
    if (mode == "cameras") renderCams = toRenderCameras(v.cameras);
    const int64_t count = mode == "targets" ? int64_t(v.views.targets.size()) : int64_t(renderCams.size());

    // Outputs are written into the staged directory as each chunk is rendered: the host holds
    // one chunk of views, however long the path.
    StagedDir staged(v.outDir);
    RenderLayout layout;
    layout.viewFormat = a.format;
    layout.width = w;
    layout.height = h;
    layout.labels = v.labels;
    layout.featureChannels = cfg.semanticDim;
    // A --path is a smooth camera move: also written as path.mp4 / path.gif (views beside label maps).
    if (mode == "path" && count > 1) {
      layout.animationFps = kPathFps;
      layout.animation = v.animation;
    }
    RenderWriter writer(staged.path(), layout);
    double writeMs = 0;
    // After each render call: label maps on the device from its semantic features, features
    // read back, everything written.
    auto writeChunk = [&](const std::vector<float>& rgb, int64_t n) {
      std::vector<std::vector<int32_t>> maps;
      std::vector<float> scores, features;
      if (req.semanticFeatures) {
        const Tensor& feats = pipeline.renderedFeatures();
        if (a.features) features = engine.download(feats);
        if (a.labels) {
          const auto tl = Clock::now();
          LabelMapsOut out = computeLabelMaps(engine, feats, text, a.scores ? &scores : nullptr);
          maps = std::move(out.maps);
          labelGpuMs += out.gpuMs;
          labelBuildMs += out.buildMs;
          labelWallMs += msSince(tl);
          labelBytesAfter = std::max<uint64_t>(labelBytesAfter, engine.memory().bytesInUse());
          labelPeak = engine.memory().peakBytes();
        }
      }
      const auto tw = Clock::now();
      RenderedViews views;
      views.count = n;
      views.rgb = rgb.data();
      views.labelMaps = a.labels ? &maps : nullptr;
      views.scores = a.scores ? &scores : nullptr;
      views.features = a.features ? &features : nullptr;
      writer.addViews(views);
      writeMs += msSince(tw);
    };
    if (count > 0) {
      const std::string views = count == 1 ? " view" : " views";
      const std::string what = mode == "targets" ? " target" + views
                               : mode == "path"  ? views + " along the input cameras"
                                                 : views + " from " + a.cameras;
      const std::string rendering = "rendering " + std::to_string(count) + what;
      progress.step(rendering);
      if (mode == "targets") {
        writeChunk(pipeline.renderTargets(), count);
      } else {
        // A long path in chunks: device memory for a few views at a time, not for all N.
        for (size_t j0 = 0; j0 < renderCams.size(); j0 += kRenderChunk) {
          const size_t j1 = std::min(renderCams.size(), j0 + kRenderChunk);
          if (j0 > 0) progress.step(rendering + " (" + std::to_string(j0) + " written)");
          RenderCameras chunk;
          chunk.c2w.assign(renderCams.c2w.begin() + j0, renderCams.c2w.begin() + j1);
          chunk.fxfycxcy.assign(renderCams.fxfycxcy.begin() + j0, renderCams.fxfycxcy.begin() + j1);
          writeChunk(pipeline.render(chunk), int64_t(j1 - j0));
        }
      }
    }

    CamerasDocument cd;
    cd.width = w;
    cd.height = h;
    cd.files = v.views.files;
    cd.inputs = v.views.inputs;
    cd.targets = v.views.targets;
    cd.canonicalIndex = enc.canonicalIndex;
    for (size_t i = 0; i < v.views.files.size(); ++i) cd.cameras.push_back(estimatedCamera(enc, int64_t(i)));
    cd.render = mode;
    if (mode != "targets") cd.renderCameras = fromRenderCameras(renderCams);

    progress.step("writing " + v.outDir);
    t = Clock::now();
    // The prepared input views (what the model saw), for the page's inputs with their masks.
    const size_t plane = size_t(3) * size_t(h) * size_t(w);
    for (size_t k = 0; k < v.views.inputs.size(); ++k) {
      char name[32];
      std::snprintf(name, sizeof name, "input_%02zu.png", k);
      const float* img = v.images.data() + size_t(v.views.inputs[k]) * plane;
      writePng((fs::path(staged.path()) / name).string(), img, 3, h, w);
    }
    const std::vector<float> noMotion;
    writer.finish(a.assumeStatic ? noMotion : enc.motionInput, a.assumeStatic ? 0 : int64_t(v.views.inputs.size()),
                  cfg.maskThreshold, cd);
    if (!enc.refinedInput.empty()) writer.writeRefined(enc.refinedInput, int64_t(v.views.inputs.size()));
    int written = writer.files() + int(v.views.inputs.size());
    host.push_back({{"name", "write_outputs"}, {"wall_ms", writeMs + msSince(t)}});

    nlohmann::ordered_json stages = nlohmann::ordered_json::array();
    // gpu_ms: compute only; build_ms: the driver building kernels during the stage (first
    // dispatches on llvmpipe); wall_ms includes both and pipeline creation.
    for (const auto& s : pipeline.stageTimes())
      stages.push_back({{"name", s.name}, {"gpu_ms", s.gpuMs}, {"build_ms", s.buildMs}, {"wall_ms", s.wallMs},
                        {"device_bytes_after", s.deviceBytesAfter}, {"device_peak_bytes", s.devicePeakBytes}});
    if (a.labels) {
      stages.push_back({{"name", "text_encoder"}, {"gpu_ms", text.gpuMs}, {"build_ms", text.buildMs},
                        {"wall_ms", text.wallMs}, {"device_bytes_after", textBytesAfter}, {"device_peak_bytes", textPeak}});
      stages.push_back({{"name", "labels"}, {"gpu_ms", labelGpuMs}, {"build_ms", labelBuildMs}, {"wall_ms", labelWallMs},
                        {"device_bytes_after", labelBytesAfter}, {"device_peak_bytes", labelPeak}});
    }
    nlohmann::ordered_json report = {
        {"tool", "spar"},
        {"command", "render"},
        {"model", absolutePath(a.model)},
        {"device", engine.caps().name},
        {"precision", a.precision},
        {"views",
         {{"total", v.views.files.size()},
          {"inputs", v.views.inputs.size()},
          {"targets", v.views.targets.size()},
          {"rendered", count}}},
        {"render", mode},
        // the size the views were prepared and rendered at, and whether --size chose it
        {"image_size", {{"height", h}, {"width", w}, {"from", a.height ? "--size" : "model"}}},
        {"assume_static", a.assumeStatic},
        // SAM2.1 refinement (only when asked): which masks gated the tokens, and per input view
        // what SAM2 decided (refined_XX.png beside mask_XX.png)
        {"refine", refineReport(enc, a.maskSource, req.refine || a.maskSource == "refined")},
        // from the start of the command to here: everything but writing this file
        {"total_seconds", msSince(start) / 1000.0},
        {"stages", stages},          // GPU stages that ran (pipeline.stageTimes())
        {"host_stages", host},       // CPU-side phases of the command
        {"kernels", kernelReport(engine)},  // pipelines: creation, driver builds, compute
        // device memory at its peak, and how many buffers and submissions it took (the counts
        // EngineOptions::faults numbers: tests/test_spar_faults.cpp)
        {"device_memory",
         {{"peak_bytes", engine.memory().peakBytes()},
          {"estimated_min_bytes", need.total()},       // model/memory_estimate.h: the lower bound
          {"estimated_max_bytes", need.upperBytes},    // and the upper bound
          {"estimated_weight_bytes", need.weightBytes},  // of which weights (as weights_bytes_loaded)
          {"budget_bytes", budget},
          {"max_input_views", maxInputs},  // this many input views surely fit budget_bytes at this size
          {"allocations", engine.memory().allocations()},
          {"submissions", engine.submissions()}}},
        {"weights_bytes_loaded", pipeline.weightBytesLoaded() + (text.weights ? text.weights->bytesLoaded() : 0)},
    };
    // what the model file says it is (a demonstration model's card): the page opens with it
    if (const auto& card = v.model->modelCard()) report["model_note"] = modelCardClaim(*card);
    // --path: which animation was written, and how (path.mp4 through ffmpeg, or path.gif and why)
    if (!writer.animationFile().empty())
      report["animation"] = {{"file", writer.animationFile()}, {"how", writer.animationDescription()}};
    writeJson((fs::path(staged.path()) / "report.json").string(), report);
    ++written;
    // Last: the page that shows it all (index_page.h), with the warnings of this render.
    writeIndexPage(staged.path(), report, camerasJson(cd), takeWarnings());
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
