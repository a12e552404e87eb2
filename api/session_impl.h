// What a spar::Session holds (api/session.cpp, api/session_labels.cpp).
#pragma once
#include <string>
#include <vector>

#include "api/api_impl.h"
#include "model/spar_pipeline.h"
#include "spar/session.h"

namespace spar {

struct Session::Impl {
  Engine& engine;
  const PackedModel& model;
  SparPipelineOptions options;
  SparPipeline pipeline;
  bool features = false;  // the last request asked for semantic features
  bool rendered = false;  // a render call since the last encode
  std::vector<std::string> prompts;  // whose embeddings the pipeline holds
  std::vector<std::string> promptWarnings;
  Impl(Engine& e, const PackedModel& m, const SparPipelineOptions& o) : engine(e), model(m), options(o), pipeline(e, m, o) {}
};

}  // namespace spar
