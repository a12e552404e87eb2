// The network parts the pipeline's stages run (model/pipeline_stage.h), each built from its
// weights when a stage first needs it, so that a request that skips a stage never uploads them.
// Some serve several stages: the view tokenizer (image tokens, ray tokens, the renderer's
// queries) and the gating (input tokens, semantic tokens).
#pragma once
#include <memory>

#include "engine/engine.h"
#include "model/cv_drp.h"
#include "model/dino_v3.h"
#include "model/gating.h"
#include "model/lseg.h"
#include "model/packed_model.h"
#include "model/pose_estimator.h"
#include "model/renderer.h"
#include "model/sam2_refinement.h"
#include "model/scene_encoder.h"
#include "model/semantic_tokens.h"
#include "model/spar_config.h"
#include "model/view_tokens.h"
#include "model/weight_set.h"

namespace spar {

struct StageModels {
  StageModels(Engine& engine, const PackedModel& model, const SparConfig& config, WeightSet& weights)
      : engine(engine), model(model), config(config), weights(weights) {}

  ViewTokenizer& tokenizer();
  PoseEstimator& pose();
  DinoV3& dino();
  CvDrp& cvDrp();
  TokenGating& gating();
  LSegEncoder& lseg();
  SemanticTokens& semantic();
  SceneEncoder& scene();
  Renderer& renderer();
  Sam2Refiner& sam2();

  Engine& engine;
  const PackedModel& model;
  const SparConfig& config;
  WeightSet& weights;

 private:
  std::unique_ptr<ViewTokenizer> tokenizer_;
  std::unique_ptr<PoseEstimator> pose_;
  std::unique_ptr<DinoV3> dino_;
  std::unique_ptr<CvDrp> cvDrp_;
  std::unique_ptr<TokenGating> gating_;
  std::unique_ptr<LSegEncoder> lseg_;
  std::unique_ptr<SemanticTokens> semantic_;
  std::unique_ptr<SceneEncoder> scene_;
  std::unique_ptr<Renderer> renderer_;
  std::unique_ptr<Sam2Refiner> sam2_;
};

}  // namespace spar
