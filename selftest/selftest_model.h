// The self-test model of the self-test (include/spar/selftest.h): a small SPAR with every stage of
// the photometric model (data/selftest, made by tests/python/make_selftest_model.py, installed
// as share/spar/selftest) run on the engine stage by stage against the PyTorch reference's
// float64 outputs it ships with, under the bounds the model tests use (model/stage_tolerances.h).
#pragma once
#include <string>
#include <vector>

#include "engine/engine.h"
#include "selftest/selftest_checks.h"

namespace spar::selftest {

// Where the self-test model is: `explicitDir` when given, else $SPAR_SELFTEST_DATA, else
// share/spar/selftest beside the running program's bin/ (an installed package), else the source
// tree this program was built from. "" when none of those holds a manifest.json.
std::string findSelftestModel(const std::string& explicitDir);
// The places findSelftestModel looks, for the message when it finds none.
std::string selftestModelSearchPath(const std::string& explicitDir);

// One check per stage output the model's manifest lists (its time: the wall time of the
// pipeline stage that made it, kernel builds included), the motion masks compared pixel by
// pixel. A model that cannot be read or run is one failing check with the one-line reason.
std::vector<SelftestCheck> runSelftestModel(Engine& engine, const std::string& dir);

}  // namespace spar::selftest
