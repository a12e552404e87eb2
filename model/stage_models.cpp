// model/stage_models.h: each network part built at its first use.
#include "model/stage_models.h"

#include "model/sam2_config.h"

namespace spar {
namespace {

template <class T, class... Args>
T& lazily(std::unique_ptr<T>& held, Args&&... args) {
  if (!held) held = std::make_unique<T>(std::forward<Args>(args)...);
  return *held;
}

}  // namespace

ViewTokenizer& StageModels::tokenizer() { return lazily(tokenizer_, engine, weights, config); }
PoseEstimator& StageModels::pose() { return lazily(pose_, engine, weights, config); }
DinoV3& StageModels::dino() { return lazily(dino_, engine, weights, config.dino); }
CvDrp& StageModels::cvDrp() { return lazily(cvDrp_, engine, weights, config); }
TokenGating& StageModels::gating() { return lazily(gating_, engine, weights, config); }
LSegEncoder& StageModels::lseg() { return lazily(lseg_, engine, weights, config); }
SemanticTokens& StageModels::semantic() { return lazily(semantic_, engine, weights, config); }
SceneEncoder& StageModels::scene() { return lazily(scene_, engine, weights, config); }
Renderer& StageModels::renderer() { return lazily(renderer_, engine, weights, config, tokenizer()); }
Sam2Refiner& StageModels::sam2() {
  return lazily(sam2_, engine, Sam2Config::fromJson(model.metadata().at("sam2_config")), sam2Weights(weights));
}

}  // namespace spar
