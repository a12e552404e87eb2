// spar: the command-line tool of the engine.
//   spar render --model M.spar (--images A B [--targets C D] | --frames f0 .. --inputs 0,3,4)
//               [--cameras transforms.json|COLMAP_DIR | --path N] [--assume-static] [--size HxW] [--device D] --out DIR
//   spar render --model M.spar --jobs JOBS.jsonl [--shard I/N] [--redo] [common options]
//   spar eval --model M.spar --scenes DIR [--views 2,3,4] [--precision fp32|fp16] [--size HxW]
//             [--no-gating | --assume-static] [--max-scenes N] [--shard I/N] [--redo] [--device D] --out result.json
//   spar eval --merge R1.json R2.json ... --out ALL.json
//   spar selftest [--device D | --all-devices] [--json] [--junit FILE]   (exit 0 only if every check passed)
// Exit codes: 0 done, 1 something found wrong on the way (files, model, device), 2 a command
// line that cannot mean anything. Every error is one line "spar: error: <message>" on stderr.
#include <CLI/CLI.hpp>

#include <cstdint>
#include <cstdio>
#include <iostream>
#include <new>
#include <string>
#include <tuple>

#include "tools/common/errors.h"
#include "tools/spar/eval_command.h"
#include "tools/spar/render_command.h"
#include "tools/spar/render_jobs.h"
#include "tools/common/selftest_command.h"
#include "spar/precision.h"

namespace {

// Messages of exceptions may span lines (a file's own text inside); the contract is one line.
std::string oneLine(std::string s) {
  for (char& c : s)
    if (c == '\n' || c == '\r') c = ' ';
  while (!s.empty() && s.back() == ' ') s.pop_back();
  return s.empty() ? "unknown error" : s;
}

int fail(const std::string& message, int code) {
  std::fprintf(stderr, "spar: error: %s\n", oneLine(message).c_str());
  return code;
}

// --size "HxW" (height first, as the converter's --size) -> positive height and width; only the
// syntax is judged here, what the model can run at once it is open (imageSizeProblem).
bool parseSize(const std::string& text, int64_t& height, int64_t& width) {
  const size_t x = text.find_first_of("xX");
  if (x == std::string::npos) return false;
  auto side = [](const std::string& t, int64_t& out) {
    if (t.empty() || t.size() > 6 || t.find_first_not_of("0123456789") != std::string::npos) return false;
    out = std::stoll(t);
    return out > 0;
  };
  return side(text.substr(0, x), height) && side(text.substr(x + 1), width);
}

const char* kSizeHelp =
    "image size HxW in pixels (height x width), multiples of the model's patch size (16; 32 with the "
    "semantic branch); default: the model's own (its training size, from spar-convert)";

// `spar render`: its options into `cmd`.
struct RenderCommand {
  spar::cli::RenderArgs a;
  std::string inputs, renderSize, jobsFile, shardText = "0/1", labelsText;
  int path = 0;
  bool redoJobs = false;
  CLI::App* app = nullptr;
  CLI::Option *targets = nullptr, *pathOpt = nullptr, *renderSizeOpt = nullptr, *jobsOpt = nullptr, *labels = nullptr;
};

void addRenderCommand(CLI::App& app, RenderCommand& cmd) {
  using namespace spar::cli;
  RenderArgs& a = cmd.a;
  CLI::App* render = cmd.app = app.add_subcommand(
      "render",
      "Run SPAR on one ordered sequence of views and write view_XX.png (rendered views), motion_XX.png / "
      "mask_XX.png (input views), cameras.json and report.json into a new directory");
  render->add_option("--model", a.model, "packed model (.spar, made by converter/spar-convert)")->required();
  auto* images = render->add_option("--images", a.views.images, "input views; the sequence is these, then --targets");
  auto* frames = render->add_option("--frames", a.views.frames,
                                    "all frames in capture order; --inputs says which are inputs, the rest are targets");
  frames->excludes(images);
  auto* targets = cmd.targets = render->add_option("--targets", a.views.targets, "target views (evaluation: rendered with "
                                                                   "their estimated cameras)");
  render->add_option("--inputs", cmd.inputs, "with --frames or --video: positions of the input views, e.g. 0,3,4");
  auto* video = render->add_option("--video", a.views.video,
                                   "take the views from a video file (any format ffmpeg reads; rotation metadata "
                                   "honoured): --video-frames of them spread evenly over the clip, then as --frames "
                                   "(default inputs: the model's input view count spread evenly, the rest targets)");
  video->excludes(images)->excludes(frames);
  render->add_option("--video-frames", a.views.videoFrames,
                     "with --video: frames taken, evenly spread (default: the model's view count)")
      ->needs(video);
  render->add_option("--video-at", a.views.videoAt, "with --video: the frames at these times, seconds (e.g. 0.5,2,3.25)")
      ->needs(video)
      ->type_name("T1,T2,...");
  auto* cameras = render->add_option("--cameras", a.cameras,
                                     "render these cameras instead of the targets (nerfstudio transforms.json, "
                                     "OpenGL camera-to-world in the canonical view's frame; or a COLMAP "
                                     "text model: its directory or images.txt)");
  auto* pathOpt = cmd.pathOpt = render->add_option("--path", cmd.path,
                                     "render N cameras along the estimated input cameras (slerp rotations, "
                                     "lerp positions) instead of the targets");
  pathOpt->excludes(cameras);
  render->add_option("--precision", a.precision,
                     "fp32; fp16: weight matrices held as fp16 on the device (half the memory); q8 / q4: the "
                     "transformer blocks' and linear layers' matrices as 8- or 4-bit codes with a scale per 32 "
                     "(0.28 / 0.16 of fp32; converter/FORMAT.md). Activations and accumulation stay fp32")
      ->check(CLI::IsMember(spar::precisionNames()));
  cmd.renderSizeOpt = render->add_option("--size", cmd.renderSize, kSizeHelp)->type_name("HxW");
  auto* assumeStaticOpt = render->add_flag("--assume-static", a.assumeStatic,
                                           "the scene is static: skip DINOv3 and CV-DRP, gate no token, write no motion maps");
  render->add_flag("--refine", a.refine,
                   "refine the inputs' motion masks with SAM2.1 (refined_XX.png; a model packed with spar-convert "
                   "--sam2)")
      ->excludes(assumeStaticOpt);
  render->add_option("--mask-source", a.maskSource,
                     "which masks gate the input tokens: raw (CV-DRP's, the default) or refined (SAM2.1's; implies "
                     "--refine)")
      ->check(CLI::IsMember({"raw", "refined"}))
      ->excludes(assumeStaticOpt);
  auto* outOpt = render->add_option("--out", a.out,
                                    "output directory (must not exist; written as DIR.tmp-XXXXXX, then renamed)");
  auto* jobsOpt = cmd.jobsOpt = render->add_option("--jobs", cmd.jobsFile,
                                     "many renders in one process (one device, kernels compiled once): a JSON Lines "
                                     "file, one job a line with its \"out\" and views (docs/many-scenes.md)");
  jobsOpt->excludes(images)->excludes(frames)->excludes(targets)->excludes(outOpt);
  render->add_option("--shard", cmd.shardText, "with --jobs: run the jobs whose position is I modulo N")
      ->type_name("I/N")
      ->needs(jobsOpt);
  render->add_flag("--redo", cmd.redoJobs,
                   "with --jobs: render every job again (by default a job whose output directory exists, which "
                   "only a finished job leaves, is skipped: a rerun finishes what is missing)")
      ->needs(jobsOpt);
  render->add_option("--device", a.device, "Vulkan device index or part of its name (default: SPAR_DEVICE, else "
                                           "the first GPU)");
  cmd.labels = render->add_option("--labels", cmd.labelsText,
                                    "comma-separated prompts: open-vocabulary label maps of the rendered views "
                                    "(labels_XX.png / .json; models with the semantic branch and CLIP text)")
                     ->type_name("\"a,b,...\"");
  render->add_flag("--features", a.features,
                   "also write the semantic features of the rendered views (features_XX.npy, C x H/2 x "
                   "W/2 float32; models with the semantic branch)");

  render->add_option("--format", a.format,
                     "file format of the rendered views: png (8-bit), exr (float32 OpenEXR), exr16 (half "
                     "OpenEXR), npy (float32 3 x H x W): the float formats hold the RGB as computed")
      ->check(CLI::IsMember({"png", "exr", "exr16", "npy"}));
  render->add_option("--animation", a.animation,
                     "the --path animation: mp4 (H.264 through ffmpeg, which must be installed), gif, or auto "
                     "(mp4 when ffmpeg is found, else gif; SPAR_FFMPEG names another ffmpeg)")
      ->check(CLI::IsMember({"auto", "mp4", "gif"}));
  render->add_flag("--scores", a.scores,
                   "with --labels: also write each view's per-label score maps (scores_XX.npy, P x H/2 x W/2 "
                   "float32: the scaled cosine similarities, the official logits before their x2 bilinear "
                   "upsampling; the labels are the argmax of the upsampled scores, at H x W)");
}

// `spar eval`: its options into `cmd`.
struct EvalCommand {
  spar::cli::EvalArgs e;
  std::string evalSize, evalShard;
  std::vector<std::string> mergeFiles;
  CLI::App* app = nullptr;
  CLI::Option *evalModel = nullptr, *evalScenes = nullptr, *evalSizeOpt = nullptr, *maxScenes = nullptr,
              *evalShardOpt = nullptr, *mergeOpt = nullptr;
};

void addEvalCommand(CLI::App& app, EvalCommand& cmd) {
  using namespace spar::cli;
  EvalArgs& e = cmd.e;
  CLI::App* evalCmd = cmd.app = app.add_subcommand(
      "eval",
      "Evaluate a model on a directory of test scenes as evaluation/PROTOCOL.md says: static-pixel "
      "PSNR / SSIM of the rendered targets, motion-mask IoU, semantic mIoU; writes result.json and prints a table");
  auto* evalModel = cmd.evalModel = evalCmd->add_option("--model", e.model, "packed model (.spar)");
  auto* evalScenes = cmd.evalScenes =
      evalCmd->add_option("--scenes", e.scenes, "directory of scene_* folders (scenes/spar-scenes split --split test)");
  evalCmd->add_option("--views", e.views, "numbers of input views K, comma-separated (default 2,3,4)")
      ->type_name("\"2,3,4\"");
  evalCmd->add_option("--precision", e.precision, "fp32, fp16, q8 or q4 weight matrices on the device (see render)")
      ->check(CLI::IsMember(spar::precisionNames()));
  cmd.evalSizeOpt = evalCmd->add_option("--size", cmd.evalSize, std::string(kSizeHelp) + "; the scenes must be this size")
                          ->type_name("HxW");
  auto* noGating = evalCmd->add_flag("--no-gating", e.noGating,
                                     "ablation: CV-DRP runs (mask metrics reported) but no input token is gated");
  auto* evalAssumeStatic =
      evalCmd->add_flag("--assume-static", e.assumeStatic, "ablation: no DINOv3 / CV-DRP, no gating, mask metrics null")
          ->excludes(noGating);
  evalCmd->add_flag("--refine", e.refine,
                    "also refine every frame's motion mask with SAM2.1 and report its IoU beside CV-DRP's (the "
                    "paper's two rows; a model packed with spar-convert --sam2)")
      ->excludes(evalAssumeStatic);
  evalCmd->add_option("--mask-source", e.maskSource,
                      "which masks gate the input tokens: raw (CV-DRP's, the default) or refined (SAM2.1's; implies "
                      "--refine)")
      ->check(CLI::IsMember({"raw", "refined"}))
      ->excludes(evalAssumeStatic);
  cmd.maxScenes =
      evalCmd->add_option("--max-scenes", e.maxScenes, "evaluate only the first N scenes (in folder-name order)");
  evalCmd->add_option("--device", e.device, "Vulkan device index or part of its name");
  auto* evalShardOpt = cmd.evalShardOpt = evalCmd->add_option("--shard", cmd.evalShard,
                                           "evaluate the scenes whose position is I modulo N (one process per "
                                           "shard under a batch system)")
                           ->type_name("I/N");
  evalCmd->add_option("--out", e.out, "result JSON file (written whole: temporary name, then rename)")->required();
  evalCmd->add_flag("--redo", e.redo,
                    "evaluate every scene again (by default a rerun of the same command keeps --out when it holds "
                    "this evaluation, and the scenes an interrupted run finished, kept in OUT.partial)");
  cmd.mergeOpt = evalCmd->add_option("--merge", cmd.mergeFiles,
                                       "combine the results of the shards of one evaluation (--shard I/N) into the "
                                       "whole set's, exactly: pooled from their per-scene sums and counts")
                       ->type_name("R1.json R2.json ...")
                       ->excludes(evalModel)
                       ->excludes(evalScenes)
                       ->excludes(evalShardOpt);
}

// `spar selftest`: its options into `st`.
CLI::App* addSelftestCommand(CLI::App& app, spar::cli::SelftestArgs& st) {
  CLI::App* selftest = app.add_subcommand(
      "selftest",
      "Check the engine on this device and driver: the device's limits (after SPAR_DEVICE_LIMITS), the kernel "
      "plan, every op family on odd and stiff shapes against float64 on the host, the self-test model stage by "
      "stage against its float64 reference outputs, the validation layer's messages; exit 0 only if everything "
      "passed");
  CLI::Option* selftestDevice = selftest->add_option(
      "--device", st.device,
      "Vulkan device index or part of its name (\"swiftshader\": SwiftShader where a browser package installed it)");
  selftest->add_flag("--all-devices", st.allDevices,
                     "every Vulkan device, SwiftShader's too where installed: one table with a column per device; "
                     "exit 0 only if every device passed")
      ->excludes(selftestDevice);
  selftest->add_flag("--json", st.json, "the report as JSON on stdout");
  selftest->add_option("--junit", st.junit,
                       "also write the checks as a JUnit XML report to FILE (one testcase per check, failures as "
                       "failures; written whole)")
      ->type_name("FILE");
  selftest->add_option("--model-dir", st.model,
                       "the self-test model's directory (default: $SPAR_SELFTEST_DATA, else share/spar/selftest "
                       "of the installed package, else the source tree's data/selftest)");
  return selftest;
}

// Each subcommand once parsed: an exit code (errors one line on stderr).
int runEvalCommand(EvalCommand& cmd) {
  using namespace spar::cli;
  EvalArgs& e = cmd.e;
  if (cmd.mergeOpt->count() == 0 && (cmd.evalModel->count() == 0 || cmd.evalScenes->count() == 0))
    return fail(std::string(cmd.evalModel->count() == 0 ? "--model" : "--scenes") +
                    " is required (or --merge R1.json R2.json ...; see spar eval --help)",
                kExitUsage);
  if (cmd.maxScenes->count() > 0 && e.maxScenes < 1)
    return fail("--max-scenes must be at least 1 (see spar eval --help)", kExitUsage);
  if (cmd.evalSizeOpt->count() > 0 && !parseSize(cmd.evalSize, e.height, e.width))
    return fail("--size must be HxW in pixels, e.g. 128x128, got '" + cmd.evalSize + "' (see spar eval --help)",
                kExitUsage);
  try {
    if (cmd.mergeOpt->count() > 0) {
      runEvalMerge(cmd.mergeFiles, e.out);
      return kExitOk;
    }
    if (cmd.evalShardOpt->count() > 0) std::tie(e.shard, e.shards) = parseShard(cmd.evalShard);
    runEval(e);
    return kExitOk;
  } catch (const UsageError& err) {
    return fail(std::string(err.what()) + " (see spar eval --help)", kExitUsage);
  } catch (const std::bad_alloc&) {
    return fail("out of host memory: the request needs more than this machine has", kExitRuntime);
  } catch (const std::exception& err) {
    return fail(err.what(), kExitRuntime);
  }
}

int runRenderCommand(RenderCommand& cmd) {
  using namespace spar::cli;
  RenderArgs& a = cmd.a;
  a.views.inputs = cmd.inputs;
  a.views.targetsGiven = cmd.targets->count() > 0;
  if (cmd.pathOpt->count() > 0) a.path = cmd.path;
  if (cmd.labels->count() > 0) a.labels = cmd.labelsText;
  if (cmd.renderSizeOpt->count() > 0 && !parseSize(cmd.renderSize, a.height, a.width))
    return fail("--size must be HxW in pixels, e.g. 128x128, got '" + cmd.renderSize + "' (see spar render --help)",
                kExitUsage);

  try {
    if (cmd.jobsOpt->count() > 0) {
      const auto [shard, shards] = parseShard(cmd.shardText);
      return runRenderJobs(readRenderJobs(cmd.jobsFile, a), shard, shards, cmd.redoJobs) ? kExitRuntime : kExitOk;
    }
    runRender(a);
    return kExitOk;
  } catch (const UsageError& e) {
    return fail(std::string(e.what()) + " (see spar render --help)", kExitUsage);
  } catch (const std::bad_alloc&) {
    return fail("out of host memory: the request needs more than this machine has", kExitRuntime);
  } catch (const std::exception& e) {
    return fail(e.what(), kExitRuntime);
  }
}

}  // namespace

int main(int argc, char** argv) {
  using namespace spar::cli;
  CLI::App app{"spar: SPAR on Vulkan: cameras, motion masks and novel views from a few photos"};
  app.require_subcommand(1);
  RenderCommand render;
  addRenderCommand(app, render);
  EvalCommand eval;
  addEvalCommand(app, eval);
  SelftestArgs st;
  CLI::App* selftest = addSelftestCommand(app, st);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() == 0) return app.exit(e);  // --help
    return fail(std::string(e.what()) + " (see --help)", kExitUsage);
  }
  if (selftest->parsed()) {
    try {
      return runSelftest(st) ? kExitOk : kExitRuntime;
    } catch (const std::exception& err) {
      return fail(err.what(), kExitRuntime);
    }
  }
  if (eval.app->parsed()) return runEvalCommand(eval);
  return runRenderCommand(render);
}
