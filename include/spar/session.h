// Runs SPAR requests of one model on one context, in two phases so that the cameras to render
// may depend on the estimated ones:
//
//   spar::Context context;                                   // a Vulkan device
//   spar::Model model = spar::Model::open("model.spar");
//   spar::Session session(context, model);
//   spar::Request request;                                    // spar/request.h
//   request.images = ...;  request.plan = {3, {0, 1, 2}, {}}; // 3 input views
//   const spar::Encoded& e = session.encode(request);         // cameras, motion masks
//   std::vector<float> rgb = session.render(cameras);         // [R, 3, H, W] in [0, 1]
//
// Only what a request needs runs (no motion prediction with assumeStatic, no semantic head
// unless semanticFeatures). A Session is not thread-safe; the Context and Model must outlive it.
#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "spar/context.h"
#include "spar/export.h"
#include "spar/memory.h"
#include "spar/model.h"
#include "spar/precision.h"
#include "spar/request.h"

namespace spar {

struct SessionOptions {
  bool profile = true;                    // per-stage GPU times (stageTimes())
  Precision precision = Precision::FP32;  // of the weight matrices on the device (spar/precision.h)
  // Keep every stage's output on the device under its name (intermediate()); costs memory.
  bool keepIntermediates = false;
};

class SPAR_API Session {
 public:
  Session(Context& context, const Model& model, const SessionOptions& options = {});
  ~Session();
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;

  // The device memory a request needs (spar/memory.h), before any work; `use` says what else
  // will be asked of the session (views a render call, label prompts). On a GPU the first call
  // measures the kernel choice, so that the estimate sees what the request will run.
  MemoryEstimate estimateMemory(const Request& request, const RenderUse& use = {});

  // Phase 1: everything up to the scene tokens. Throws spar::Error (one line) for bad requests,
  // and before any work for a request whose least need is above the device's memory budget
  // (MemoryEstimate::refusal).
  const Encoded& encode(const Request& request);
  // Phase 2 (after encode): the plan's target views with their estimated cameras, or the given
  // cameras. RGB [R, 3, H, W] in [0, 1].
  std::vector<float> renderTargets();
  std::vector<float> render(const RenderCameras& cameras);
  // The semantic features [R, C, H/2, W/2] of the last render call (requests with
  // semanticFeatures on a semantic model; else empty).
  std::vector<float> features();

  // The prompts' CLIP text embeddings, computed now on the device and kept for label maps with
  // the same prompts (labelMaps computes them itself when not prepared). Prompts longer than
  // CLIP's 77 tokens are cut there, each with a line in *warnings when given. Needs a model that
  // carries CLIP's tokenizer (spar-convert --bpe). Throws spar::Error (one line).
  void preparePrompts(const std::vector<std::string>& prompts, std::vector<std::string>* warnings = nullptr);
  // Open-vocabulary label maps of the last render call: per rendered view, the index of the
  // prompt whose CLIP text embedding best matches each pixel's semantic feature (first maximum),
  // [H * W] row-major at the image's size, in the official order: the half-resolution scores
  // enlarged x2 (bilinear, align_corners) before the argmax. With `scores`, the per-prompt
  // scores [R, P, H/2, W/2] (the official logits before the enlargement) are appended to it.
  // Needs a request with semanticFeatures. Throws spar::Error (one line).
  std::vector<std::vector<int32_t>> labelMaps(const std::vector<std::string>& prompts,
                                              std::vector<std::string>* warnings = nullptr,
                                              std::vector<float>* scores = nullptr);

  // Stages that ran since construction, in order (a stage that ran again adds to its entry):
  // the pipeline's, then "text_encoder" and "labels" once label maps were made.
  const std::vector<StageTime>& stageTimes() const;
  // Bytes of weights uploaded to the device so far (the text encoder's included).
  uint64_t weightBytesLoaded() const;

  // With SessionOptions::keepIntermediates: the names of the stage outputs kept by the last
  // encode and render calls (the PyTorch reference's golden names: "img_tokens", "c2w", ...,
  // "rgb"), and one of them read back with its shape. Throws spar::Error for a name not kept.
  std::vector<std::string> intermediateNames() const;
  std::vector<float> intermediate(const std::string& name, std::vector<int64_t>* shape = nullptr) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace spar
