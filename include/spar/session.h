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
#include "spar/model.h"
#include "spar/request.h"

namespace spar {

struct SessionOptions {
  bool profile = true;       // per-stage GPU times (stageTimes())
  bool fp16Weights = false;  // weight matrices as fp16 on the device (half the memory)
};

class SPAR_API Session {
 public:
  Session(Context& context, const Model& model, const SessionOptions& options = {});
  ~Session();
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;

  // Phase 1: everything up to the scene tokens. Throws spar::Error (one line) for bad requests.
  const Encoded& encode(const Request& request);
  // Phase 2 (after encode): the plan's target views with their estimated cameras, or the given
  // cameras. RGB [R, 3, H, W] in [0, 1].
  std::vector<float> renderTargets();
  std::vector<float> render(const RenderCameras& cameras);
  // The semantic features [R, C, H/2, W/2] of the last render call (requests with
  // semanticFeatures on a semantic model; else empty).
  std::vector<float> features();
  // Open-vocabulary label maps of the last render call: per rendered view, the index of the
  // prompt whose CLIP text embedding best matches each pixel's semantic feature (first maximum),
  // [H * W] row-major at the image's size, in the official order: the half-resolution scores
  // enlarged x2 (bilinear, align_corners) before the argmax. Needs a request with semanticFeatures and a model that carries CLIP's
  // tokenizer (spar-convert --bpe); the prompts' embeddings are kept for the next call with the
  // same prompts. Prompts longer than CLIP's 77 tokens are cut there, each with a line in
  // *warnings when given. Throws spar::Error (one line).
  std::vector<std::vector<int32_t>> labelMaps(const std::vector<std::string>& prompts,
                                              std::vector<std::string>* warnings = nullptr);

  // Stages that ran since construction, in order.
  const std::vector<StageTime>& stageTimes() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace spar
