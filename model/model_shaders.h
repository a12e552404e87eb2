// SPAR's own kernels (model/shaders/: token_gate, plucker_rays, pose_head), kept out of the
// engine's general op set. The host code dispatching them calls registerModelShaders() before
// asking the engine for their kernels.
#pragma once

namespace spar {

void registerModelShaders();  // idempotent, thread-safe

}  // namespace spar
