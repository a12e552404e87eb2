// Which stages a request runs, in order (model/pipeline_stage.h): what it does not need is not in
// its list. Encode: image tokens, pose estimator, rays; DINOv3 and CV-DRP unless the scene is
// declared static; SAM2.1's refinement when asked; gating; LSeg (unless its features come with
// the request) and the semantic tokens on models with the semantic branch; the scene encoder.
// Render: the renderer. Prompts and labels: CLIP's text encoder and the label maps, with labels.
// SparPipeline runs the list phase by phase; the memory estimate adds it up.
#pragma once
#include "model/packed_model.h"
#include "model/pipeline_stage.h"

namespace spar {

StageList pipelineStages(const StageSizing& sizing);

// Every module of the packed file, at most, that some stage of a maximal request loads: what a
// test checks the file's tensors against (no tensor without a stage that loads it).
std::vector<std::string> stageModules(const StageSizing& sizing);

}  // namespace spar
