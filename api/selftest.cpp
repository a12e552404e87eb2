// spar::runSelftestOn (include/spar/selftest.h): one device's self-test, the engine on it with
// the validation layer where installed, its limits and kernel plan, the op checks
// (selftest/selftest_checks.h) and the self-test model stage by stage (selftest/selftest_model.h).
#include "spar/selftest.h"

#include <memory>

#include "api/api_impl.h"
#include "selftest/selftest_checks.h"
#include "selftest/selftest_model.h"

namespace spar {

SelftestReport runSelftestOn(const std::string& device, const std::string& modelDir) {
  EngineOptions base;
  base.device = device;
  base.pipelineCacheFile = EngineOptions::defaultPipelineCacheFile();
  EngineOptions options = EngineOptions::fromEnvironment(base);
  // The validation layer where it is installed (its messages count against the verdict).
  options.validation = true;
  SelftestReport r;
  std::unique_ptr<Context> context;
  try {
    context = std::make_unique<Context>(options);
  } catch (const std::exception& e) {
    if (std::string(e.what()).find("VK_LAYER_KHRONOS_validation is not installed") == std::string::npos) throw;
    options.validation = false;
    r.validationNote = "not installed (apt-get install vulkan-validationlayers to check the engine's Vulkan use)";
    context = std::make_unique<Context>(options);
  }
  Engine& engine = context->impl().engine;
  r.info = context->device();
  r.device = r.info.name + ", " + r.info.driver;
  r.profile = r.info.limitsProfile.empty() ? "" : options.limits.describe();
  r.plan = context->kernelPlan();
  r.opChecks = selftest::runSelftestChecks(engine);
  r.modelDir = selftest::findSelftestModel(modelDir);
  if (r.modelDir.empty()) {
    SelftestCheck missing{"model", "-"};
    missing.error = "the self-test model is not in " + selftest::selftestModelSearchPath(modelDir) +
                    " (reinstall the package, or --model-dir DIR)";
    r.modelChecks.push_back(std::move(missing));
  } else {
    r.modelChecks = selftest::runSelftestModel(engine, r.modelDir);
  }
  r.validation = options.validation;
  r.validationMessages = context->validationMessages();
  return r;
}

}  // namespace spar
