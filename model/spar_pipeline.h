// SPAR's photometric pipeline on the engine, stage by stage as the paper's Figure 2 draws it
// (reference: reference/spar_reference/spar.py SPAR.forward and SPAR.render):
//
//   images -> image tokens (+ spatial-temporal codes)        model/view_tokens.*
//          -> pose encoder over [camera tokens, image tokens] model/pose_estimator.*
//          -> rel_head / canonical_k_head -> cameras          model/pose_head.*
//          -> Plücker rays -> ray tokens                      model/plucker_rays.*, model/view_tokens.*
//          -> DINOv3 patch tokens                             model/dino_v3.*
//          -> CV-DRP motion probability per view              model/cv_drp.*
//          -> (asked for) SAM2.1 refinement of the masks        model/sam2_refinement.*
//          -> mlp_fuse + soft_with_pe gating                  model/gating.*
//          -> (semantic models) LSeg features -> semantic tokens, gated  model/lseg.*, model/semantic_tokens.*
//          -> scene encoder -> scene tokens                   model/scene_encoder.*
//   render: ray queries + scene tokens -> decoder -> RGB head model/renderer.*
//
// Work happens in two phases so that rendering cameras may depend on the estimated ones (a path
// through the input cameras): encode() runs everything up to the scene tokens and leaves the
// cameras and motion maps on the host; render*() decodes any number of views from the scene
// tokens kept on the device. Only what a request needs runs: no CV-DRP or DINOv3 with
// assumeStatic, no CV-DRP over targets unless targetMotion, no target view nobody renders.
#pragma once
#include <array>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "engine/engine.h"
#include "spar/request.h"
#include "model/packed_model.h"
#include "model/spar_config.h"
#include "model/weight_set.h"

namespace spar {

class NonFiniteWatch;  // model/nonfinite_watch.h

// The request types are public (include/spar/request.h); the pipeline's own names for them:
using SparRequest = Request;
using SparEncoded = Encoded;

// "" when the engine runs this model at height x width pixels, else why not (one line, no
// prefix). Any size works whose sides are positive multiples of the patch size: the sin-cos
// codes and DINOv3's RoPE are computed for the grid in hand (non-square grids as the official
// code builds them), LSeg's position embeddings are resized to it, and CV-DRP's decoder
// upsamples any grid by 16. With the semantic branch the sides must be
// multiples of 32 (LSeg's fusion). The configuration's image size is the training size, the
// default; the model was not trained at other sizes, so its results there may be worse.
std::string imageSizeProblem(const SparConfig& config, int64_t height, int64_t width);

// "" when the model can refine motion masks (packed with spar-convert --sam2), else why not
// (one line, no prefix): what a request with refine, and the CLI's --refine, are refused with.
std::string refinementProblem(const PackedModel& model);


struct SparPipelineOptions {
  bool profile = true;            // per-dispatch timestamps -> stageTimes()
  // Keep every stage's output tensor under its golden name (reference/spar_reference/
  // goldens.py: "img_tokens", "pose_encoder_out", "c2w", ..., "rgb") for tests; costs memory.
  bool keepIntermediates = false;
  // Weight matrices on the device: F32 as the file stores them (F16 in a `spar-convert --fp16`
  // pack); F16 as fp16 even from an F32 file, with the values that pack would hold. Norms,
  // biases, learned tokens and codes stay F32; activations are F32 either way.
  DType weightType = DType::F32;
};

class SparPipeline {
 public:
  // Parses the configuration; weights are uploaded lazily as stages first need them.
  SparPipeline(Engine& engine, const PackedModel& model, const SparPipelineOptions& options = {});
  ~SparPipeline();
  SparPipeline(const SparPipeline&) = delete;
  SparPipeline& operator=(const SparPipeline&) = delete;

  const SparConfig& config() const { return config_; }

  // Phase 1. Throws spar::Error (one line) for bad requests (sizes, plan).
  const SparEncoded& encode(const SparRequest& request);
  // Phase 2 (after encode): the plan's targets with their estimated cameras, or explicit
  // cameras. Returns RGB [R, 3, H, W] in [0, 1].
  std::vector<float> renderTargets();
  std::vector<float> render(const RenderCameras& cameras);
  // The semantic features [R, C, H/2, W/2] of the last render*() call on the device (undefined
  // unless the request asked for semanticFeatures); valid until the next render*() call.
  const Tensor& renderedFeatures() const { return features_; }

  // Stages that ran since construction (in order, accumulated by name).
  const std::vector<StageTime>& stageTimes() const { return stageTimes_; }
  uint64_t weightBytesLoaded() const { return weights_.bytesLoaded(); }
  const WeightSet& weights() const { return weights_; }

  // With keepIntermediates: the device tensor stored under a golden name (throws if absent).
  const Tensor& intermediate(const std::string& name) const;
  std::vector<std::string> intermediateNames() const;

 private:
  struct Stages;
  void keep(const std::string& name, const Tensor& t);
  void addStageTimes(const class Recorder& rec, double wallMs);
  void addStageTime(const std::string& name, double gpuMs, double wallMs, double buildMs);  // accumulated by name
  std::vector<float> renderRays(const Tensor& c2w, const Tensor& fxfycxcy, int64_t count);
  Tensor refineMasks(const Tensor& images, const Tensor& probInput, const Tensor& probTarget);

  Engine& engine_;
  const PackedModel& model_;
  SparPipelineOptions options_;
  SparConfig config_;
  WeightSet weights_;
  std::unique_ptr<Stages> stages_;
  std::unique_ptr<NonFiniteWatch> watch_;  // where a NaN / infinity first appeared
  SparEncoded encoded_;
  SparRequest request_;
  std::map<std::string, Tensor> kept_;
  Tensor features_;
  std::vector<StageTime> stageTimes_;
};

}  // namespace spar
