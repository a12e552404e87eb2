#include "model/model_shaders.h"

#include "engine/shader_registry.h"

namespace spar {

const std::vector<EmbeddedShader>& modelShaders();  // generated from model/shaders/

void registerModelShaders() { registerShaders(modelShaders()); }

}  // namespace spar
