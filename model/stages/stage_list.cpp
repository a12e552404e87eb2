#include "model/stages/stage_list.h"

#include <set>

#include "model/stages/stages.h"

namespace spar {

StageList pipelineStages(const StageSizing& s) {
  const RequestShape& q = s.shape;
  const SparConfig& c = s.config;
  StageList list;
  list.push_back(stages::imageTokens());
  list.push_back(stages::poseEstimator());
  list.push_back(stages::rays());
  if (!q.assumeStatic) {
    list.push_back(stages::dinoV3());
    list.push_back(stages::cvDrp());
  }
  if (q.refine && s.model.metadata().count("sam2_config")) list.push_back(stages::sam2Refine());
  list.push_back(stages::gating());
  if (c.useLseg) {
    if (!q.lsegGiven) list.push_back(stages::lseg());
    list.push_back(stages::semanticTokens());
  }
  list.push_back(stages::sceneEncoder());
  list.push_back(stages::renderer());
  if (q.labels) {
    list.push_back(stages::textEncoder());
    list.push_back(stages::labels());
  }
  return list;
}

std::vector<std::string> stageModules(const StageSizing& s) {
  RequestShape most = s.shape;
  most.assumeStatic = false;
  most.refine = most.semantic = most.labels = most.targetMotion = true;
  most.lsegGiven = false;
  const StageSizing sizing{s.model, s.config, most};
  std::set<std::string> modules;
  for (const auto& stage : pipelineStages(sizing))
    for (const std::string& m : stage->weightModules(sizing)) modules.insert(m);
  return {modules.begin(), modules.end()};
}

}  // namespace spar
