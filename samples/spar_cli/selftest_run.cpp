// One device's self-test (selftest_run.h).
#include "samples/spar_cli/selftest_run.h"

#include <memory>

#include "engine/engine.h"
#include "samples/spar_cli/selftest_model.h"

namespace spar::cli {

size_t SelftestReport::passed() const {
  size_t n = 0;
  for (const auto* list : {&opChecks, &modelChecks})
    for (const SelftestCheck& c : *list) n += c.passed();
  return n;
}

SelftestReport runSelftestOn(const std::string& device, const std::string& modelDir) {
  EngineOptions base;
  base.device = device;
  base.pipelineCacheFile = EngineOptions::defaultPipelineCacheFile();
  EngineOptions options = EngineOptions::fromEnvironment(base);
  // The validation layer where it is installed (its messages count against the verdict).
  options.validation = true;
  SelftestReport r;
  std::unique_ptr<Engine> engine;
  try {
    engine = std::make_unique<Engine>(options);
  } catch (const std::exception& e) {
    if (std::string(e.what()).find("VK_LAYER_KHRONOS_validation is not installed") == std::string::npos) throw;
    options.validation = false;
    r.validationNote = "not installed (apt-get install vulkan-validationlayers to check the engine's Vulkan use)";
    engine = std::make_unique<Engine>(options);
  }
  r.caps = engine->caps();
  r.device = r.caps.name + ", " + r.caps.driverInfo;
  r.profile = r.caps.limitsProfile.empty() ? "" : options.limits.describe();
  r.plan = describePlan(engine->plan(), r.caps);
  r.opChecks = runSelftestChecks(*engine);
  r.modelDir = findSelftestModel(modelDir);
  if (r.modelDir.empty()) {
    SelftestCheck missing{"model", "-"};
    missing.error = "the self-test model is not in " + selftestModelSearchPath(modelDir) +
                    " (reinstall the package, or --model-dir DIR)";
    r.modelChecks.push_back(std::move(missing));
  } else {
    r.modelChecks = runSelftestModel(*engine, r.modelDir);
  }
  r.validation = options.validation;
  r.validationMessages = engine->device().validationMessageCount();
  return r;
}

}  // namespace spar::cli
