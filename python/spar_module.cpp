// `import spar`: the public C++ interface (include/spar/) for Python, through pybind11.
// Images and outputs are NumPy float32 arrays, channels first; outputs own their memory (the
// library's vectors, handed over without a copy). Every failure is a spar.Error with the
// library's one-line message. Device work runs with the GIL released, so other Python threads
// go on; calls on one Context are serialized (the engine behind it is not thread-safe), so two
// sessions on one context may be used from two threads.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "spar/spar.h"

namespace py = pybind11;

namespace {

// A Context and the lock its sessions' device work takes.
struct ContextBox {
  spar::Context context;
  std::mutex lock;
  explicit ContextBox(const spar::EngineOptions& options) : context(options) {}
};

struct SessionBox {
  std::shared_ptr<ContextBox> ctx;
  std::shared_ptr<spar::Model> model;  // the Session reads it: kept alive as long
  std::unique_ptr<spar::Session> session;
  spar::Encoded encoded;
  int64_t height = 0, width = 0;  // of the last encode
  int64_t rendered = 0;           // views of the last render call

  spar::Session& open() {
    if (!session) throw spar::Error("this session is closed");
    return *session;
  }
};

// A vector's memory as a NumPy array of `shape`, without a copy: the array owns the vector.
template <typename T>
py::array_t<T> toNumpy(std::vector<T>&& values, const std::vector<py::ssize_t>& shape) {
  auto* owned = new std::vector<T>(std::move(values));
  py::capsule free(owned, [](void* p) { delete static_cast<std::vector<T>*>(p); });
  return py::array_t<T>(shape, owned->data(), free);
}

std::string shapeText(const py::array& a) {
  std::string s = "(";
  for (py::ssize_t i = 0; i < a.ndim(); ++i) s += (i ? ", " : "") + std::to_string(a.shape(i));
  return s + (a.ndim() == 1 ? ",)" : ")");
}

// `a` as float32 values of the given rank (-1 in `dims`: any size); a spar::Error naming `what`
// for another dtype, rank or size, or a NaN / infinity.
std::vector<float> floats(const py::handle& h, const char* what, std::vector<py::ssize_t> dims) {
  if (!py::isinstance<py::array>(h)) throw spar::Error(std::string(what) + ": expected a NumPy float32 array");
  const py::array a = py::reinterpret_borrow<py::array>(h);
  if (!a.dtype().is(py::dtype::of<float>()))
    throw spar::Error(std::string(what) + ": dtype " + std::string(py::str(a.dtype())) + ", expected float32");
  bool ok = a.ndim() == py::ssize_t(dims.size());
  for (size_t i = 0; ok && i < dims.size(); ++i) ok = dims[i] < 0 || a.shape(py::ssize_t(i)) == dims[i];
  if (!ok) {
    std::string want = "(";
    for (size_t i = 0; i < dims.size(); ++i) want += (i ? ", " : "") + (dims[i] < 0 ? std::string("n") : std::to_string(dims[i]));
    throw spar::Error(std::string(what) + ": shape " + shapeText(a) + ", expected " + want + ")");
  }
  const auto c = py::array_t<float, py::array::c_style | py::array::forcecast>::ensure(a);
  std::vector<float> v(c.data(), c.data() + c.size());
  size_t bad = 0;
  for (float x : v) bad += !std::isfinite(x);
  if (bad) throw spar::Error(std::string(what) + ": " + std::to_string(bad) + " values are NaN or infinite");
  return v;
}

spar::RenderCameras camerasFrom(const py::handle& c2wIn, const py::handle& kIn) {
  const std::vector<float> c2w = floats(c2wIn, "c2w", {-1, 4, 4});
  const std::vector<float> k = floats(kIn, "fxfycxcy", {-1, 4});
  if (c2w.size() / 16 != k.size() / 4)
    throw spar::Error("c2w holds " + std::to_string(c2w.size() / 16) + " cameras, fxfycxcy " + std::to_string(k.size() / 4));
  spar::RenderCameras cams;
  for (size_t i = 0; i < k.size() / 4; ++i) {
    std::array<float, 16> m;
    std::array<float, 4> kk;
    std::copy_n(c2w.begin() + ptrdiff_t(i * 16), 16, m.begin());
    std::copy_n(k.begin() + ptrdiff_t(i * 4), 4, kk.begin());
    cams.c2w.push_back(m);
    cams.fxfycxcy.push_back(kk);
  }
  return cams;
}

py::tuple camerasTo(const spar::RenderCameras& cams) {
  std::vector<float> c2w, k;
  for (size_t i = 0; i < cams.size(); ++i) {
    c2w.insert(c2w.end(), cams.c2w[i].begin(), cams.c2w[i].end());
    k.insert(k.end(), cams.fxfycxcy[i].begin(), cams.fxfycxcy[i].end());
  }
  const auto n = py::ssize_t(cams.size());
  return py::make_tuple(toNumpy(std::move(c2w), {n, 4, 4}), toNumpy(std::move(k), {n, 4}));
}

// RGB [R, 3, H, W] from a render call.
py::array_t<float> rgbArray(std::vector<float>&& rgb, SessionBox& s) {
  const auto plane = py::ssize_t(3 * s.height * s.width);
  s.rendered = plane ? int64_t(rgb.size()) / plane : 0;
  return toNumpy(std::move(rgb), {py::ssize_t(s.rendered), 3, py::ssize_t(s.height), py::ssize_t(s.width)});
}

void warn(const std::string& message) { PyErr_WarnEx(PyExc_UserWarning, message.c_str(), 1); }

// A request's view plan and options as encode and estimate_memory take them: inputs None = every
// view, targets None = the views that are not inputs.
void setPlanAndOptions(spar::Request& r, int64_t views, const py::object& inputs, const py::object& targets,
                       bool assumeStatic, bool targetMotion, bool semanticFeatures, bool refine,
                       const std::string& maskSource) {
  if (maskSource != "raw" && maskSource != "refined")
    throw spar::Error("mask_source must be 'raw' or 'refined', got '" + maskSource + "'");
  r.plan.views = views;
  if (inputs.is_none()) {
    for (int64_t i = 0; i < views; ++i) r.plan.inputs.push_back(i);
  } else {
    r.plan.inputs = inputs.cast<std::vector<int64_t>>();
  }
  if (targets.is_none()) {
    for (int64_t i = 0; i < views; ++i)
      if (std::find(r.plan.inputs.begin(), r.plan.inputs.end(), i) == r.plan.inputs.end()) r.plan.targets.push_back(i);
  } else {
    r.plan.targets = targets.cast<std::vector<int64_t>>();
  }
  r.assumeStatic = assumeStatic;
  r.targetMotion = targetMotion;
  r.semanticFeatures = semanticFeatures;
  r.refine = refine;
  r.maskSource = maskSource == "refined" ? spar::MaskSource::Refined : spar::MaskSource::Raw;
}

}  // namespace

namespace {

// The public report types as dicts (spar/context.h, spar/kernel_report.h, spar/memory.h).
py::dict deviceDict(const spar::DeviceInfo& d) {
  py::dict o;
  o["name"] = d.name;
  o["driver"] = d.driver;
  o["vulkan"] = std::to_string(d.vulkanMajor) + "." + std::to_string(d.vulkanMinor);
  o["limits_profile"] = d.limitsProfile;
  o["max_texel_buffer_elements"] = d.maxTexelBufferElements;
  o["max_storage_buffer_range"] = d.maxStorageBufferRange;
  o["max_compute_shared_memory_size"] = d.maxComputeSharedMemorySize;
  o["max_compute_workgroup_invocations"] = d.maxComputeWorkGroupInvocations;
  o["shader_float16"] = d.shaderFloat16;
  o["fp16_storage"] = d.fp16Storage;
  o["subgroup_size"] = d.subgroupSize;
  o["subgroup_arithmetic"] = d.subgroupArithmetic;
  o["cooperative_matrix"] = d.cooperativeMatrix;
  return o;
}

py::dict kernelDict(const spar::KernelReport& r) {
  py::list kernels;
  for (const spar::KernelStats& k : r.kernels)
    kernels.append(py::dict(py::arg("name") = k.name, py::arg("create_ms") = k.createMs, py::arg("builds") = k.builds,
                            py::arg("compiles") = k.compiles, py::arg("build_ms") = k.buildMs,
                            py::arg("dispatches") = k.dispatches, py::arg("gpu_ms") = k.gpuMs));
  return py::dict(py::arg("plan") = r.plan, py::arg("pipelines") = r.pipelines, py::arg("create_ms") = r.createMs,
                  py::arg("builds") = r.builds, py::arg("compiles") = r.compiles, py::arg("build_ms") = r.buildMs,
                  py::arg("dispatches") = r.dispatches, py::arg("compute_ms") = r.computeMs, py::arg("kernels") = kernels);
}

py::dict memoryDict(const spar::MemoryStats& m) {
  return py::dict(py::arg("bytes_in_use") = m.bytesInUse, py::arg("peak_bytes") = m.peakBytes,
                  py::arg("budget_bytes") = m.budgetBytes, py::arg("budget_source") = m.budgetSource,
                  py::arg("allocations") = m.allocations, py::arg("submissions") = m.submissions);
}

py::dict estimateDict(const spar::MemoryEstimate& e) {
  return py::dict(py::arg("min_bytes") = e.minBytes, py::arg("max_bytes") = e.maxBytes,
                  py::arg("weight_bytes") = e.weightBytes, py::arg("activation_bytes") = e.activationBytes,
                  py::arg("budget_bytes") = e.budgetBytes, py::arg("budget_source") = e.budgetSource,
                  py::arg("max_input_views") = e.maxInputViews, py::arg("refusal") = e.refusal,
                  py::arg("warning") = e.warning);
}

}  // namespace

PYBIND11_MODULE(spar, m) {
  m.doc() =
      "SPAR on Vulkan compute: from 2-4 photos of a scene, the cameras, which pixels move, and new views "
      "(RGB, semantic features, open-vocabulary label maps).\n\n"
      "    ctx = spar.Context()\n"
      "    model = spar.Model.open('model.spar')\n"
      "    h, w = model.image_size\n"
      "    images = np.stack([spar.load_image(p, h, w) for p in paths])   # (V, 3, H, W) float32\n"
      "    with spar.Session(ctx, model) as s:\n"
      "        enc = s.encode(images, inputs=[0, 2])                       # cameras, motion\n"
      "        rgb = s.render_targets()                                    # (R, 3, H, W)\n\n"
      "Every failure raises spar.Error (one line).";

  static py::exception<spar::Error> error(m, "Error", PyExc_RuntimeError);
  error.doc() = "Every failure of the engine, the model file or a call's arguments: one line.";
  // Anything else the library throws (std::bad_alloc, ...) is a spar.Error too.
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const spar::Error& e) {
      error(e.what());
    } catch (const py::error_already_set&) {
      throw;
    } catch (const py::builtin_exception&) {
      throw;
    } catch (const std::exception& e) {
      error(e.what());
    }
  });

  m.def("list_devices", &spar::Context::listDevices, "'index: name (type)' of every Vulkan device on this machine.");
  m.def("precisions", &spar::precisionNames, "The weight precisions a Session takes: 'fp32', 'fp16', 'q8', 'q4'.");

  py::class_<ContextBox, std::shared_ptr<ContextBox>>(m, "Context",
                                                    "One Vulkan device with its memory and compiled kernels. Keep "
                                                    "one per device: kernels compiled for one request serve the next.")
      .def(py::init([](const std::string& device, py::object validation, const std::string& limits) {
             spar::EngineOptions o = spar::EngineOptions::fromEnvironment();
             if (!device.empty()) o.device = device;
             if (!validation.is_none()) o.validation = validation.cast<bool>();
             if (!limits.empty()) o.limits = spar::DeviceLimits::parse(limits);
             py::gil_scoped_release free;
             return std::make_shared<ContextBox>(o);
           }),
           py::arg("device") = "", py::arg("validation") = py::none(), py::arg("limits") = "",
           "device: an index or part of a device's name ('' = SPAR_DEVICE, else the first GPU, else a CPU "
           "device); validation: the Khronos validation layer (None = SPAR_VALIDATION); limits: a device-limit "
           "profile ('vulkan-1.2-min', 'raspberry-pi-5', ... or a JSON file; '' = SPAR_DEVICE_LIMITS).")
      .def_property_readonly("device_name", [](ContextBox& c) { return c.context.deviceName(); })
      .def_property_readonly("validation_messages", [](ContextBox& c) { return c.context.validationMessages(); },
                             "Messages the validation layer reported so far.")
      .def_property_readonly("device", [](ContextBox& c) { return deviceDict(c.context.device()); },
                             "The device as the engine uses it (after any device-limit profile): name, driver, "
                             "vulkan, limits and features.")
      .def(
          "kernel_plan",
          [](ContextBox& c) {
            std::lock_guard<std::mutex> hold(c.lock);
            return c.context.kernelPlan();
          },
          "The kernel family per op on this device and why, one line each.")
      .def(
          "kernel_report",
          [](ContextBox& c) {
            std::lock_guard<std::mutex> hold(c.lock);
            return kernelDict(c.context.kernelReport());
          },
          "Every kernel made so far (creation, driver builds, dispatches, compute time), with the plan and totals.")
      .def(
          "memory", [](ContextBox& c) { return memoryDict(c.context.memory()); },
          "Device memory: bytes_in_use, peak_bytes, budget_bytes, budget_source, allocations, submissions.");

  py::class_<spar::Model, std::shared_ptr<spar::Model>>(m, "Model", "A packed SPAR model (.spar, made by spar-convert).")
      .def_static(
          "open",
          [](const std::string& path) {
            py::gil_scoped_release free;
            return std::make_shared<spar::Model>(spar::Model::open(path));
          },
          py::arg("path"), "Opens and checks a .spar file (every header field before any tensor byte).")
      .def_property_readonly("path", &spar::Model::path)
      .def_property_readonly("image_size", [](const spar::Model& mo) { return py::make_tuple(mo.imageHeight(), mo.imageWidth()); },
                             "(height, width) the model was configured for: what images are prepared to.")
      .def_property_readonly("patch_size", &spar::Model::patchSize)
      .def_property_readonly("semantic", &spar::Model::semantic, "Has the semantic branch (features, label maps).")
      .def_property_readonly("has_tokenizer", &spar::Model::hasTokenizer, "Carries CLIP's tokenizer (text prompts).")
      .def_property_readonly("demonstration_note", &spar::Model::demonstrationNote,
                             "What the file says it is when it is a demonstration model (one sentence with its "
                             "measured quality), else ''.")
      .def_property_readonly("feature_channels", &spar::Model::featureChannels,
                             "Channels of its semantic features (0 without the semantic branch).")
      .def_property_readonly("mask_threshold", &spar::Model::maskThreshold, "P(dynamic) above it is a moving pixel.")
      .def_property_readonly("refinement_problem", &spar::Model::refinementProblem,
                             "'' when the model can refine motion masks (SAM2.1 packed in), else why not.")
      .def("size_problem", &spar::Model::sizeProblem, py::arg("height"), py::arg("width"),
           "'' when the engine runs the model at height x width, else why not.")
      .def("prompt_warnings", &spar::Model::promptWarnings, py::arg("prompts"),
           "What tokenizing the prompts would warn about (prompts cut at CLIP's 77 tokens), without device work.");

  py::class_<SessionBox>(m, "Session",
                        "Requests of one model on one context, in two phases: encode() the photos (cameras, motion), "
                        "then render() any cameras. Not for two threads at once; two sessions may be.")
      .def(py::init([](std::shared_ptr<ContextBox> ctx, std::shared_ptr<spar::Model> model, const std::string& precision,
                       bool keepIntermediates) {
             auto s = std::make_unique<SessionBox>();
             s->ctx = ctx;
             s->model = model;
             spar::SessionOptions o;
             o.precision = spar::parsePrecision(precision);
             o.keepIntermediates = keepIntermediates;
             s->session = std::make_unique<spar::Session>(ctx->context, *model, o);
             return s;
           }),
           py::arg("context"), py::arg("model"), py::arg("precision") = "fp32", py::arg("keep_intermediates") = false,
           "precision: of the weight matrices on the device, 'fp32', 'fp16' (half the memory; where the device "
           "reads fp16), 'q8' or 'q4' (8- / 4-bit codes, a scale per 32). keep_intermediates: every stage's output "
           "kept for intermediate().")
      .def(
          "encode",
          [](SessionBox& s, const py::handle& images, py::object inputs, py::object targets, bool assumeStatic,
             bool targetMotion, bool semanticFeatures, bool refine, const std::string& maskSource,
             const py::object& refinePrompts) {
            spar::Request r;
            r.images = floats(images, "images", {-1, 3, -1, -1});
            const py::array a = py::reinterpret_borrow<py::array>(images);
            const int64_t views = a.shape(0);
            r.height = a.shape(2);
            r.width = a.shape(3);
            setPlanAndOptions(r, views, inputs, targets, assumeStatic, targetMotion, semanticFeatures, refine, maskSource);
            if (!refinePrompts.is_none()) r.refinePrompts = floats(refinePrompts, "refine_prompts", {views, r.height, r.width});
            spar::Session& session = s.open();
            {
              py::gil_scoped_release free;
              std::lock_guard<std::mutex> hold(s.ctx->lock);
              s.encoded = session.encode(r);
            }
            s.height = r.height;
            s.width = r.width;
            s.rendered = 0;
            py::dict out;
            const auto v = py::ssize_t(s.encoded.c2w.size() / 16);
            out["c2w"] = toNumpy(std::vector<float>(s.encoded.c2w), {v, 4, 4});
            out["fxfycxcy"] = toNumpy(std::vector<float>(s.encoded.fxfycxcy), {v, 4});
            const auto hw = py::ssize_t(r.height * r.width);
            auto motion = [&](const std::vector<float>& p) -> py::object {
              if (p.empty()) return py::none();
              return toNumpy(std::vector<float>(p), {py::ssize_t(p.size()) / hw, py::ssize_t(r.height), py::ssize_t(r.width)});
            };
            out["motion_input"] = motion(s.encoded.motionInput);
            out["motion_target"] = motion(s.encoded.motionTarget);
            out["canonical_index"] = s.encoded.canonicalIndex;
            if (!s.encoded.refineViews.empty()) {
              out["refined_input"] = motion(s.encoded.refinedInput);
              out["refined_target"] = motion(s.encoded.refinedTarget);
              py::list views;
              for (const spar::RefinedView& rv : s.encoded.refineViews) {
                py::dict d;
                d["view"] = rv.view;
                d["skipped"] = rv.skipped;
                d["dynamic_pixels"] = rv.dynamicPixels;
                d["iou"] = rv.skipped ? py::object(py::none()) : py::object(py::make_tuple(rv.iou[0], rv.iou[1], rv.iou[2]));
                d["chosen"] = rv.skipped ? py::object(py::none()) : py::object(py::int_(rv.chosen));
                d["logits"] = rv.skipped ? py::object(py::none()) : toNumpy(std::vector<float>(rv.logits), {256, 256});
                views.append(d);
              }
              out["refine_views"] = views;
            }
            return out;
          },
          py::arg("images"), py::arg("inputs") = py::none(), py::arg("targets") = py::none(),
          py::arg("assume_static") = false, py::arg("target_motion") = false, py::arg("semantic_features") = false,
          py::arg("refine") = false, py::arg("mask_source") = "raw", py::arg("refine_prompts") = py::none(),
          "images: float32 (V, 3, H, W) in [0, 1] in capture order (spar.load_image prepares a file); inputs: "
          "positions of the input views (default all); targets: the views to render with render_targets() "
          "(default the rest). Returns a dict: c2w (V, 4, 4) OpenCV camera-to-world in the canonical view's "
          "frame, fxfycxcy (V, 4) normalized intrinsics, motion_input (K, H, W) P(dynamic) of the inputs "
          "(None with assume_static), motion_target (T, H, W) with target_motion, canonical_index. refine: "
          "SAM2.1 refinement of the masks (a model packed with spar-convert --sam2): adds refined_input (K, H, W) "
          "and refined_target (T, H, W with target_motion) of 0 / 1 and refine_views (per refined view: view, "
          "skipped, dynamic_pixels, iou, chosen, logits 256 x 256); mask_source 'refined' gates the input tokens "
          "with them (implies refine); refine_prompts: float32 (V, H, W) P(dynamic) to refine instead of CV-DRP's.")
      .def(
          "render_targets",
          [](SessionBox& s) {
            spar::Session& session = s.open();
            std::vector<float> rgb;
            {
              py::gil_scoped_release free;
              std::lock_guard<std::mutex> hold(s.ctx->lock);
              rgb = session.renderTargets();
            }
            return rgbArray(std::move(rgb), s);
          },
          "The encoded request's target views from their estimated cameras: RGB float32 (T, 3, H, W) in [0, 1].")
      .def(
          "render",
          [](SessionBox& s, const py::handle& c2w, const py::handle& k) {
            const spar::RenderCameras cams = camerasFrom(c2w, k);
            spar::Session& session = s.open();
            std::vector<float> rgb;
            {
              py::gil_scoped_release free;
              std::lock_guard<std::mutex> hold(s.ctx->lock);
              rgb = session.render(cams);
            }
            return rgbArray(std::move(rgb), s);
          },
          py::arg("c2w"), py::arg("fxfycxcy"),
          "Views from any cameras (after encode): c2w float32 (R, 4, 4), fxfycxcy float32 (R, 4) as encode "
          "returns them (spar.path_cameras, spar.read_cameras make some). RGB float32 (R, 3, H, W).")
      .def(
          "features",
          [](SessionBox& s) -> py::object {
            spar::Session& session = s.open();
            std::vector<float> f;
            {
              py::gil_scoped_release free;
              std::lock_guard<std::mutex> hold(s.ctx->lock);
              f = session.features();
            }
            if (f.empty() || s.rendered == 0) return py::none();
            const auto r = py::ssize_t(s.rendered), h = py::ssize_t(s.height / 2), w = py::ssize_t(s.width / 2);
            const auto c = py::ssize_t(f.size()) / (r * h * w);
            return toNumpy(std::move(f), {r, c, h, w});
          },
          "Semantic features (R, C, H/2, W/2) of the last render call (a request with semantic_features on "
          "a semantic model), else None.")
      .def(
          "estimate_memory",
          [](SessionBox& s, int64_t views, const py::object& inputs, const py::object& targets, int64_t height,
             int64_t width, bool assumeStatic, bool targetMotion, bool semanticFeatures, bool refine,
             const std::string& maskSource, int64_t viewsPerRender, int64_t labelPrompts) {
            spar::Request r;
            setPlanAndOptions(r, views, inputs, targets, assumeStatic, targetMotion, semanticFeatures, refine, maskSource);
            r.height = height;
            r.width = width;
            spar::Session& session = s.open();
            std::lock_guard<std::mutex> hold(s.ctx->lock);
            return estimateDict(session.estimateMemory(r, {viewsPerRender, labelPrompts}));
          },
          py::arg("views"), py::arg("inputs"), py::arg("targets") = py::none(), py::arg("height") = 0,
          py::arg("width") = 0, py::arg("assume_static") = false, py::arg("target_motion") = false,
          py::arg("semantic_features") = false, py::arg("refine") = false, py::arg("mask_source") = "raw",
          py::arg("views_per_render") = -1, py::arg("label_prompts") = 0,
          "The device memory a request of this shape needs, before any work (the request's options as encode "
          "takes them; views_per_render: views a render call renders, -1 the targets; label_prompts: prompts "
          "label maps will be asked for). A dict: min_bytes (above the budget it cannot run: encode refuses "
          "it), max_bytes, weight_bytes, activation_bytes, budget_bytes, budget_source, max_input_views, "
          "refusal, warning.")
      .def(
          "prepare_prompts",
          [](SessionBox& s, const std::vector<std::string>& prompts) {
            spar::Session& session = s.open();
            std::vector<std::string> warnings;
            {
              py::gil_scoped_release free;
              std::lock_guard<std::mutex> hold(s.ctx->lock);
              session.preparePrompts(prompts, &warnings);
            }
            for (const std::string& w : warnings) warn(w);
          },
          py::arg("prompts"),
          "The prompts through CLIP's text encoder now (label_maps does it at its first call otherwise).")
      .def(
          "label_maps",
          [](SessionBox& s, const std::vector<std::string>& prompts, bool withScores) -> py::object {
            spar::Session& session = s.open();
            std::vector<std::vector<int32_t>> maps;
            std::vector<std::string> warnings;
            std::vector<float> scores;
            {
              py::gil_scoped_release free;
              std::lock_guard<std::mutex> hold(s.ctx->lock);
              maps = session.labelMaps(prompts, &warnings, withScores ? &scores : nullptr);
            }
            for (const std::string& w : warnings) warn(w);
            std::vector<int32_t> all;
            for (const auto& one : maps) all.insert(all.end(), one.begin(), one.end());
            const auto r = py::ssize_t(maps.size());
            py::object out = toNumpy(std::move(all), {r, py::ssize_t(s.height), py::ssize_t(s.width)});
            if (!withScores) return out;
            return py::make_tuple(out, toNumpy(std::move(scores), {r, py::ssize_t(prompts.size()), py::ssize_t(s.height / 2),
                                                                    py::ssize_t(s.width / 2)}));
          },
          py::arg("prompts"), py::arg("scores") = false,
          "Open-vocabulary label maps of the last render call: int32 (R, H, W), each pixel the index of "
          "the prompt whose CLIP embedding matches its semantic feature best (the official order: the "
          "half-resolution scores enlarged x2, bilinear, before the argmax). Needs semantic_features in the "
          "encode and a model with CLIP's tokenizer. scores=True: (maps, scores float32 (R, P, H/2, W/2)), the "
          "official logits before the enlargement.")
      .def_property_readonly(
          "weight_bytes_loaded", [](SessionBox& s) { return s.open().weightBytesLoaded(); },
          "Bytes of weights uploaded to the device so far (the text encoder's included).")
      .def(
          "intermediate_names", [](SessionBox& s) { return s.open().intermediateNames(); },
          "With keep_intermediates: the stage outputs kept by the last encode and render calls.")
      .def(
          "intermediate",
          [](SessionBox& s, const std::string& name) {
            spar::Session& session = s.open();
            std::vector<int64_t> shape;
            std::vector<float> values;
            {
              std::lock_guard<std::mutex> hold(s.ctx->lock);
              values = session.intermediate(name, &shape);
            }
            return toNumpy(std::move(values), std::vector<py::ssize_t>(shape.begin(), shape.end()));
          },
          py::arg("name"), "One kept stage output (float32, its shape), by its reference name ('c2w', 'rgb', ...).")
      .def(
          "stage_times",
          [](SessionBox& s) {
            py::list out;
            for (const spar::StageTime& t : s.open().stageTimes())
              out.append(py::dict(py::arg("name") = t.name, py::arg("gpu_ms") = t.gpuMs, py::arg("wall_ms") = t.wallMs,
                                  py::arg("build_ms") = t.buildMs, py::arg("device_bytes_after") = t.deviceBytesAfter,
                                  py::arg("device_peak_bytes") = t.devicePeakBytes, py::arg("dispatches") = t.dispatches,
                                  py::arg("barriers") = t.barriers, py::arg("submits") = t.submits,
                                  py::arg("transformer_blocks") = t.transformerBlocks,
                                  py::arg("block_dispatches") = t.blockDispatches));
            return out;
          },
          "The stages that ran since the session was made: name, gpu_ms (compute), build_ms (the driver's "
          "kernel builds), wall_ms, device_bytes_after (device memory in use when it ended), device_peak_bytes "
          "(the peak so far), dispatches, barriers, submits (host waits), transformer_blocks, block_dispatches (the "
          "most dispatches one transformer block took).")
      .def(
          "close",
          [](SessionBox& s) {
            py::gil_scoped_release free;
            std::lock_guard<std::mutex> hold(s.ctx->lock);
            s.session.reset();
          },
          "Frees the session's device memory now; every later call raises spar.Error.")
      .def("__enter__", [](SessionBox& s) -> SessionBox& { return s; }, py::return_value_policy::reference)
      .def("__exit__", [](SessionBox& s, py::args) {
        py::gil_scoped_release free;
        std::lock_guard<std::mutex> hold(s.ctx->lock);
        s.session.reset();
      });

  m.def(
      "load_image",
      [](const std::string& path, int height, int width) {
        std::vector<float> img;
        {
          py::gil_scoped_release free;
          img = spar::loadImage(path, height, width);
        }
        return toNumpy(std::move(img), {3, height, width});
      },
      py::arg("path"), py::arg("height"), py::arg("width"),
      "An image file prepared as SPAR's reference does (8-bit RGB, Lanczos cover-resize, centre crop, /255): "
      "float32 (3, height, width).");
  m.def(
      "load_video",
      [](const std::string& path, int height, int width, int count, const std::vector<double>& at) {
        std::vector<float> frames;
        std::vector<double> times;
        {
          py::gil_scoped_release free;
          frames = spar::loadVideoFrames(path, height, width, count, at, &times);
        }
        const auto n = py::ssize_t(times.size());
        return py::make_tuple(toNumpy(std::move(frames), {n, 3, height, width}), toNumpy(std::move(times), {n}));
      },
      py::arg("path"), py::arg("height"), py::arg("width"), py::arg("count") = 8, py::arg("at") = std::vector<double>{},
      "Frames of a video file as `spar render --video` takes them (ffmpeg must be installed): `count` spread "
      "evenly over the clip, or those shown at the seconds in `at`; turned as its rotation metadata says, "
      "cover-resized and centre-cropped to height x width. Returns (frames float32 (N, 3, H, W), times (N,)).");
  m.def(
      "write_png",
      [](const std::string& path, const py::handle& rgb) {
        if (!py::isinstance<py::array>(rgb)) throw spar::Error("rgb: expected a NumPy float32 array");
        const py::array a = py::reinterpret_borrow<py::array>(rgb);
        const std::vector<float> v = floats(rgb, "rgb", {3, -1, -1});
        spar::writePng(path, v, int(a.shape(1)), int(a.shape(2)));
      },
      py::arg("path"), py::arg("rgb"), "rgb float32 (3, H, W) in [0, 1] as an 8-bit PNG, rounded as the reference rounds.");
  m.def(
      "path_cameras",
      [](const py::dict& encoded, const std::vector<int64_t>& inputs, int count) {
        spar::Encoded e;
        e.c2w = floats(encoded["c2w"], "encoded['c2w']", {-1, 4, 4});
        e.fxfycxcy = floats(encoded["fxfycxcy"], "encoded['fxfycxcy']", {-1, 4});
        return camerasTo(spar::pathCameras(e, inputs, count));
      },
      py::arg("encoded"), py::arg("inputs"), py::arg("count"),
      "count cameras along the estimated cameras of `inputs` (the dict encode returned): (c2w, fxfycxcy) "
      "for Session.render, as `spar render --path` makes them.");
  m.def(
      "read_cameras",
      [](const std::string& path, int height, int width) {
        std::string warning;
        const spar::RenderCameras cams = spar::readCameras(path, width, height, &warning);
        if (!warning.empty()) warn(warning);
        return camerasTo(cams);
      },
      py::arg("path"), py::arg("height"), py::arg("width"),
      "The cameras of a nerfstudio transforms.json or a COLMAP text model, for a model of height x width: "
      "(c2w, fxfycxcy) for Session.render, as `spar render --cameras` reads them.");
}
