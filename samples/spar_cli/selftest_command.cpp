// spar selftest (selftest_command.h): the device and its limits, the kernel plan, the op checks
// (selftest_checks.cpp) and a verdict, as a table or as JSON.
#include "samples/spar_cli/selftest_command.h"

#include <cmath>
#include <cstdio>
#include <iostream>
#include <nlohmann/json.hpp>

#include "engine/engine.h"
#include "samples/spar_cli/selftest_checks.h"
#include "samples/spar_cli/selftest_junit.h"
#include "samples/spar_cli/selftest_model.h"

namespace spar::cli {
namespace {

std::string mib(uint64_t b) { return std::to_string(b >> 20) + " MiB"; }

nlohmann::ordered_json checkJson(const SelftestCheck& c) {
  auto bound = [](double v) { return std::isinf(v) ? nlohmann::ordered_json() : nlohmann::ordered_json(v); };
  return {{"name", c.name}, {"family", c.family}, {"nmse", c.nmse}, {"max_abs", c.maxAbs},
          {"max_nmse", c.maxNmse}, {"max_abs_limit", bound(c.maxAbsLimit)}, {"detail", c.detail}, {"ms", c.ms},
          {"finite", c.finite}, {"error", c.error}, {"passed", c.passed()}};
}

void printCheck(const SelftestCheck& c) {
  if (!c.error.empty()) {
    std::printf("  FAIL  %-52s error: %s\n", c.name.c_str(), c.error.c_str());
    return;
  }
  const char* verdict = c.passed() ? "pass" : "FAIL";
  const char* nonFinite = c.finite ? "" : "  NON-FINITE";
  if (!c.detail.empty()) {
    std::printf("  %s  %-52s %-20s %s%s  %8.1f ms\n", verdict, c.name.c_str(), c.family.c_str(), c.detail.c_str(),
                nonFinite, c.ms);
    return;
  }
  char absBound[32] = "-";
  if (!std::isinf(c.maxAbsLimit)) std::snprintf(absBound, sizeof absBound, "<= %.0e", c.maxAbsLimit);
  std::printf("  %s  %-52s %-20s nmse %.1e (<= %.0e)  max abs %.1e (%s)%s  %8.1f ms\n", verdict, c.name.c_str(),
              c.family.c_str(), c.nmse, c.maxNmse, c.maxAbs, absBound, nonFinite, c.ms);
}

nlohmann::ordered_json limitsJson(const DeviceCaps& c) {
  return {{"max_texel_buffer_elements", c.maxTexelBufferElements},
          {"max_storage_buffer_range", c.maxStorageBufferRange},
          {"max_compute_shared_memory_size", c.maxSharedMemory},
          {"max_compute_workgroup_invocations", c.maxWorkGroupInvocations},
          {"max_push_constants_size", c.maxPushConstantsSize},
          {"max_per_stage_storage_buffers", c.maxPerStageStorageBuffers},
          {"max_per_stage_texel_buffers", c.maxPerStageSampledImages},
          {"min_storage_buffer_offset_alignment", c.minStorageBufferOffsetAlignment},
          {"min_texel_buffer_offset_alignment", c.minTexelBufferOffsetAlignment},
          {"shader_float16", c.shaderFloat16},
          {"fp16_storage", c.supportsFp16Storage()},
          {"subgroup_size", c.subgroupSize},
          {"subgroup_arithmetic", c.subgroupArithmetic},
          {"cooperative_matrix", c.cooperativeMatrix}};
}

}  // namespace

bool runSelftest(const SelftestArgs& args) {
  if (!args.junit.empty()) checkJunitWritable(args.junit);  // before any work
  EngineOptions base;
  base.device = args.device;
  base.pipelineCacheFile = EngineOptions::defaultPipelineCacheFile();
  EngineOptions options = EngineOptions::fromEnvironment(base);
  // The validation layer where it is installed (its messages count against the verdict).
  options.validation = true;
  std::string validationNote;
  std::unique_ptr<Engine> engine;
  try {
    engine = std::make_unique<Engine>(options);
  } catch (const std::exception& e) {
    if (std::string(e.what()).find("VK_LAYER_KHRONOS_validation is not installed") == std::string::npos) throw;
    options.validation = false;
    validationNote = "not installed (apt-get install vulkan-validationlayers to check the engine's Vulkan use)";
    engine = std::make_unique<Engine>(options);
  }
  const DeviceCaps& caps = engine->caps();
  const std::vector<std::string> plan = describePlan(engine->plan(), caps);
  const std::vector<SelftestCheck> checks = runSelftestChecks(*engine);
  const std::string modelDir = findSelftestModel(args.model);
  std::vector<SelftestCheck> modelChecks;
  if (modelDir.empty()) {
    SelftestCheck missing{"model", "-"};
    missing.error = "the self-test model is not in " + selftestModelSearchPath(args.model) +
                    " (reinstall the package, or --model-dir DIR)";
    modelChecks.push_back(std::move(missing));
  } else {
    modelChecks = runSelftestModel(*engine, modelDir);
  }
  const size_t messages = engine->device().validationMessageCount();
  size_t passed = 0;
  for (const SelftestCheck& c : checks) passed += c.passed();
  for (const SelftestCheck& c : modelChecks) passed += c.passed();
  const size_t total = checks.size() + modelChecks.size();
  const bool ok = passed == total && messages == 0;
  if (!args.junit.empty())
    writeSelftestJunit(args.junit, {caps.name + ", " + caps.driverInfo, checks, modelChecks, options.validation, messages});

  if (args.json) {
    nlohmann::ordered_json doc;
    doc["device"] = caps.name;
    doc["driver"] = caps.driverInfo;
    doc["vulkan"] = std::to_string(VK_API_VERSION_MAJOR(caps.apiVersion)) + "." + std::to_string(VK_API_VERSION_MINOR(caps.apiVersion));
    doc["profile"] = caps.limitsProfile.empty() ? nlohmann::ordered_json() : nlohmann::ordered_json(options.limits.describe());
    doc["limits"] = limitsJson(caps);
    doc["plan"] = plan;
    doc["checks"] = nlohmann::ordered_json::array();
    for (const SelftestCheck& c : checks) doc["checks"].push_back(checkJson(c));
    doc["model"] = {{"dir", modelDir}, {"checks", nlohmann::ordered_json::array()}};
    for (const SelftestCheck& c : modelChecks) doc["model"]["checks"].push_back(checkJson(c));
    doc["validation"] = {{"enabled", options.validation}, {"messages", messages}};
    doc["passed"] = ok;
    std::cout << doc.dump(1) << "\n";
    return ok;
  }
  std::printf("spar selftest\n");
  std::printf("device     %s, %s, Vulkan %u.%u\n", caps.name.c_str(), caps.driverInfo.c_str(),
              VK_API_VERSION_MAJOR(caps.apiVersion), VK_API_VERSION_MINOR(caps.apiVersion));
  std::printf("profile    %s\n", caps.limitsProfile.empty() ? "none (the device's own limits)" : options.limits.describe().c_str());
  std::printf("limits     texel buffer %llu texels, storage binding %s, shared memory %u KiB, %u invocations, push %u B,\n"
              "           %u storage / %u texel buffers a stage, alignments %llu / %llu B, fp16 arithmetic %s, fp16 storage %s,\n"
              "           subgroup size %u, subgroup arithmetic %s, cooperative matrices %s\n",
              (unsigned long long)caps.maxTexelBufferElements, mib(caps.maxStorageBufferRange).c_str(), caps.maxSharedMemory / 1024,
              caps.maxWorkGroupInvocations, caps.maxPushConstantsSize, caps.maxPerStageStorageBuffers,
              caps.maxPerStageSampledImages, (unsigned long long)caps.minStorageBufferOffsetAlignment,
              (unsigned long long)caps.minTexelBufferOffsetAlignment, caps.shaderFloat16 ? "yes" : "no",
              caps.supportsFp16Storage() ? "yes" : "no", caps.subgroupSize, caps.subgroupArithmetic ? "yes" : "no",
              caps.cooperativeMatrix ? "yes" : "no");
  std::printf("plan\n");
  for (const std::string& line : plan) std::printf("  %s\n", line.c_str());
  std::printf("checks (against float64 on the host)\n");
  for (const SelftestCheck& c : checks) printCheck(c);
  std::printf("model %s (stage by stage against the PyTorch reference in float64; time: the stage's)\n",
              modelDir.empty() ? "not found" : modelDir.c_str());
  for (const SelftestCheck& c : modelChecks) printCheck(c);
  if (options.validation)
    std::printf("validation layer: on, %zu message%s\n", messages, messages == 1 ? "" : "s");
  else
    std::printf("validation layer: %s\n", validationNote.c_str());
  std::printf("verdict: %s (%zu of %zu checks passed%s)\n", ok ? "PASS" : "FAIL", passed, total,
              messages ? ", validation messages" : "");
  return ok;
}

}  // namespace spar::cli
