// What a request must be before SPAR's pipeline runs it (model/spar_pipeline.h): its plan, sizes,
// options and the model's branches. Each problem is one line without a prefix; the public API
// shows them as they are (spar::Model::sizeProblem, spar::Session::encode's errors).
#pragma once
#include <cstdint>
#include <string>

#include "model/packed_model.h"
#include "model/spar_config.h"
#include "spar/request.h"

namespace spar {

// "" when the engine runs this model at height x width pixels, else why not (one line, no
// prefix). Any size works whose sides are positive multiples of the patch size: the sin-cos
// codes and DINOv3's RoPE are computed for the grid in hand (non-square grids as the official
// code builds them), LSeg's position embeddings are resized to it, and CV-DRP's decoder
// upsamples any grid by 16. With the semantic branch the sides must be multiples of 32 (LSeg's
// fusion). The configuration's image size is the training size, the default; the model was not
// trained at other sizes, so its results there may be worse.
std::string imageSizeProblem(const SparConfig& config, int64_t height, int64_t width);

// "" when the model can refine motion masks (packed with spar-convert --sam2), else why not
// (one line, no prefix): what a request with refine, and the CLI's --refine, are refused with.
std::string refinementProblem(const PackedModel& model);

// Throws spar::Error (one line) for a request this model cannot run (sizes, plan, options).
void validateRequest(const SparConfig& config, const PackedModel& model, const Request& request);

}  // namespace spar
