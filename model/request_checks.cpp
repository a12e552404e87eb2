// model/request_checks.h: what a request must be before the pipeline runs it.
#include "model/request_checks.h"

#include <cmath>

#include "model/lseg.h"
#include "spar/error.h"

namespace spar {

std::string refinementProblem(const PackedModel& model) {
  return model.metadata().count("sam2_config") ? "" : "this model has no SAM2.1 weights (spar-convert --sam2)";
}

std::string imageSizeProblem(const SparConfig& config, int64_t height, int64_t width) {
  const std::string size = std::to_string(height) + "x" + std::to_string(width) + " (HxW)";
  if (height <= 0 || width <= 0 || height % config.patchSize || width % config.patchSize)
    return "image size " + size + " is not a multiple of the model's patch size " + std::to_string(config.patchSize);
  if (config.useLseg && (height % LSegEncoder::kSizeMultiple || width % LSegEncoder::kSizeMultiple))
    return "image size " + size + " is not a multiple of " + std::to_string(LSegEncoder::kSizeMultiple) +
           ", which this model's semantic branch (LSeg) needs";
  return "";
}

void validateRequest(const SparConfig& c, const PackedModel& model, const Request& request) {
  request.plan.validate();
  const int64_t h = request.height ? request.height : c.imageHeight;
  const int64_t w = request.width ? request.width : c.imageWidth;
  if (const std::string problem = imageSizeProblem(c, h, w); !problem.empty()) throw Error(problem);
  const int64_t v = request.plan.views, k = int64_t(request.plan.inputs.size());
  if (int64_t(request.images.size()) != v * 3 * h * w)
    throw Error("expected " + std::to_string(v) + " images of 3x" + std::to_string(h) + "x" + std::to_string(w) +
                " values, got " + std::to_string(request.images.size()) + " values");
  if (request.assumeStatic && request.targetMotion) throw Error("target motion masks need CV-DRP (not --assume-static)");
  if (request.semanticFeatures && !c.semanticDecoding())
    throw Error("this model has no semantic decoding (use_lseg / semantic loss weight): no semantic features");
  const int64_t featureValues = k * c.semanticDim * (h / 2) * (w / 2);
  if (!request.lsegFeatures.empty() && (!c.useLseg || int64_t(request.lsegFeatures.size()) != featureValues))
    throw Error("precomputed LSeg features: expected " + std::to_string(c.useLseg ? featureValues : 0) + " values, got " +
                std::to_string(request.lsegFeatures.size()));
  const bool refine = request.refine || request.maskSource == MaskSource::Refined;
  if (const std::string problem = refine ? refinementProblem(model) : ""; !problem.empty())
    throw Error(problem + ": no mask refinement");
  if (request.maskSource == MaskSource::Refined && request.assumeStatic)
    throw Error("refined masks gate nothing in a scene declared static (not --assume-static)");
  if (!request.refinePrompts.empty()) {
    if (!refine) throw Error("masks to refine were given without asking for refinement");
    if (int64_t(request.refinePrompts.size()) != v * h * w)
      throw Error("masks to refine: expected " + std::to_string(v) + " masks of " + std::to_string(h) + "x" +
                  std::to_string(w) + " values, got " + std::to_string(request.refinePrompts.size()) + " values");
    for (float p : request.refinePrompts)
      if (!std::isfinite(p)) throw Error("masks to refine hold a value that is not finite");
  } else if (refine && request.assumeStatic) {
    throw Error("refinement needs CV-DRP's masks (not --assume-static) or masks given to refine");
  }
}

}  // namespace spar
