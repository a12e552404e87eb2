// What the public classes (include/spar/) hold: the engine's and the model code's own types,
// which the public headers never show.
#pragma once
#include <memory>

#include "engine/engine.h"
#include "model/packed_model.h"
#include "model/spar_config.h"
#include "spar/context.h"
#include "spar/model.h"

namespace spar {

struct Context::Impl {
  Engine engine;
  explicit Impl(const EngineOptions& options) : engine(options) {}
};

struct Model::Impl {
  PackedModel file;
  SparConfig config;
};

}  // namespace spar
