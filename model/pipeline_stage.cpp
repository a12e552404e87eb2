// model/pipeline_stage.h: a stage's access to the tensors and recorder of its run.
#include "model/pipeline_stage.h"

#include "spar/error.h"

namespace spar {

Recorder& StageRun::rec() const {
  if (!recorder) throw Error("internal: a stage that records on the phase's recorder ran without one");
  return *recorder;
}

const Tensor& StageRun::at(const std::string& name) const {
  const auto it = tensors.find(name);
  if (it == tensors.end() || !it->second.defined())
    throw Error("internal: a stage reads '" + name + "', which no earlier stage of its list wrote");
  return it->second;
}

Tensor StageRun::optional(const std::string& name) const {
  const auto it = tensors.find(name);
  return it == tensors.end() ? Tensor() : it->second;
}

}  // namespace spar
