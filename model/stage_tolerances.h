// How close the engine's fp32 pipeline must come to the PyTorch reference run in float64, per
// stage output (the golden names of reference/spar_reference/goldens.py that SparPipeline keeps
// with keepIntermediates). One table for the model tests (tests/pipeline_check.cpp) and for
// `spar selftest`'s self-test model (selftest/selftest_model.cpp), so a driver passes
// the self-test only as closely as the engine passes its own tests.
#pragma once
#include <string>

namespace spar {

// The NMSE bound of the stage `goldenName` (each stage fed by the engine's previous ones, so
// the bound covers the error accumulated up to it); throws std::out_of_range for a name
// without one.
double fp32StageNmseBound(const std::string& goldenName);

// Motion masks (the ".binary" stages) must be identical, except pixels whose reference
// probability is closer than this to the threshold (a near-tie may round either way).
constexpr double kMaskTieBand = 1e-4;

// Label maps (at full resolution) must be identical, except pixels whose reference's two best
// labels score closer than this (a near-tie may go either way).
constexpr double kLabelTieGap = 1e-5;

// SAM2.1's refined masks must be identical, except pixels whose reference logit (the chosen
// mask's, resized to the view) is closer than this to 0; its IoU predictions within this of
// the reference's (issue 34's bars).
constexpr double kRefineTieBand = 1e-4;
constexpr double kRefineIouMaxAbs = 1e-5;

}  // namespace spar
