// The stages of SPAR's pipeline, one factory each (model/pipeline_stage.h; the list a request
// runs: model/stages/stage_list.h). Grouped by file as the paper's Figure 2 groups them.
#pragma once
#include <memory>

#include "model/pipeline_stage.h"

namespace spar::stages {

// view_stages.cpp: images -> image and camera tokens -> cameras -> rays and ray tokens
std::unique_ptr<PipelineStage> imageTokens();
std::unique_ptr<PipelineStage> poseEstimator();
std::unique_ptr<PipelineStage> rays();
// motion_stages.cpp: DINOv3 patch tokens -> CV-DRP's P(dynamic) per view
std::unique_ptr<PipelineStage> dinoV3();
std::unique_ptr<PipelineStage> cvDrp();
// refine_stage.cpp: SAM2.1's refinement of the motion masks
std::unique_ptr<PipelineStage> sam2Refine();
// gating_stage.cpp: mlp_fuse and the gating of the input tokens
std::unique_ptr<PipelineStage> gating();
// What gates the input and semantic tokens: the refined masks with MaskSource::Refined, else
// CV-DRP's; undefined without masks (assumeStatic) or without gating.
Tensor gateMask(const StageRun& run);
// semantic_stages.cpp: LSeg features -> semantic tokens, gated
std::unique_ptr<PipelineStage> lseg();
std::unique_ptr<PipelineStage> semanticTokens();
// scene_stage.cpp: the scene encoder
std::unique_ptr<PipelineStage> sceneEncoder();
// render_stages.cpp: a render call's rays, then the decoder and heads
std::unique_ptr<PipelineStage> renderer();
// label_stages.cpp: CLIP's text encoder, the label maps
std::unique_ptr<PipelineStage> textEncoder();
std::unique_ptr<PipelineStage> labels();

}  // namespace spar::stages
