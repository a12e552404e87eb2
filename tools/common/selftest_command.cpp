// spar selftest (selftest_command.h): one device's run (spar/selftest.h: its limits, kernel plan,
// op checks and model stages) or every device's (--all-devices, selftest_table.h), printed as a
// table or as JSON, and the JUnit report (selftest_junit.h).
#include "tools/common/selftest_command.h"

#include <cmath>
#include <cstdio>
#include <iostream>
#include <nlohmann/json.hpp>

#include "spar/selftest.h"
#include "tools/common/selftest_junit.h"
#include "tools/common/selftest_table.h"

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

nlohmann::ordered_json limitsJson(const DeviceInfo& c) {
  return {{"max_texel_buffer_elements", c.maxTexelBufferElements},
          {"max_storage_buffer_range", c.maxStorageBufferRange},
          {"max_compute_shared_memory_size", c.maxComputeSharedMemorySize},
          {"max_compute_workgroup_invocations", c.maxComputeWorkGroupInvocations},
          {"max_push_constants_size", c.maxPushConstantsSize},
          {"max_per_stage_storage_buffers", c.maxPerStageStorageBuffers},
          {"max_per_stage_texel_buffers", c.maxPerStageTexelBuffers},
          {"min_storage_buffer_offset_alignment", c.minStorageBufferOffsetAlignment},
          {"min_texel_buffer_offset_alignment", c.minTexelBufferOffsetAlignment},
          {"shader_float16", c.shaderFloat16},
          {"fp16_storage", c.fp16Storage},
          {"subgroup_size", c.subgroupSize},
          {"subgroup_arithmetic", c.subgroupArithmetic},
          {"cooperative_matrix", c.cooperativeMatrix}};
}

nlohmann::ordered_json reportJson(const SelftestReport& r) {
  nlohmann::ordered_json doc;
  if (!r.error.empty()) return {{"device", r.device}, {"error", r.error}, {"passed", false}};
  const DeviceInfo& caps = r.info;
  doc["device"] = caps.name;
  doc["driver"] = caps.driver;
  doc["vulkan"] = std::to_string(caps.vulkanMajor) + "." + std::to_string(caps.vulkanMinor);
  doc["profile"] = r.profile.empty() ? nlohmann::ordered_json() : nlohmann::ordered_json(r.profile);
  doc["limits"] = limitsJson(caps);
  doc["plan"] = r.plan;
  doc["checks"] = nlohmann::ordered_json::array();
  for (const SelftestCheck& c : r.opChecks) doc["checks"].push_back(checkJson(c));
  doc["model"] = {{"dir", r.modelDir}, {"checks", nlohmann::ordered_json::array()}};
  for (const SelftestCheck& c : r.modelChecks) doc["model"]["checks"].push_back(checkJson(c));
  doc["validation"] = {{"enabled", r.validation}, {"messages", r.validationMessages}};
  doc["passed"] = r.ok();
  return doc;
}

void printReport(const SelftestReport& r) {
  const DeviceInfo& caps = r.info;
  std::printf("spar selftest\n");
  std::printf("device     %s, %s, Vulkan %u.%u\n", caps.name.c_str(), caps.driver.c_str(), caps.vulkanMajor,
              caps.vulkanMinor);
  std::printf("profile    %s\n", r.profile.empty() ? "none (the device's own limits)" : r.profile.c_str());
  std::printf("limits     texel buffer %llu texels, storage binding %s, shared memory %u KiB, %u invocations, push %u B,\n"
              "           %u storage / %u texel buffers a stage, alignments %llu / %llu B, fp16 arithmetic %s, fp16 storage %s,\n"
              "           subgroup size %u, subgroup arithmetic %s, cooperative matrices %s\n",
              (unsigned long long)caps.maxTexelBufferElements, mib(caps.maxStorageBufferRange).c_str(),
              caps.maxComputeSharedMemorySize / 1024, caps.maxComputeWorkGroupInvocations, caps.maxPushConstantsSize,
              caps.maxPerStageStorageBuffers, caps.maxPerStageTexelBuffers,
              (unsigned long long)caps.minStorageBufferOffsetAlignment,
              (unsigned long long)caps.minTexelBufferOffsetAlignment, caps.shaderFloat16 ? "yes" : "no",
              caps.fp16Storage ? "yes" : "no", caps.subgroupSize, caps.subgroupArithmetic ? "yes" : "no",
              caps.cooperativeMatrix ? "yes" : "no");
  std::printf("plan\n");
  for (const std::string& line : r.plan) std::printf("  %s\n", line.c_str());
  std::printf("checks (against float64 on the host)\n");
  for (const SelftestCheck& c : r.opChecks) printCheck(c);
  std::printf("model %s (stage by stage against the PyTorch reference in float64; time: the stage's)\n",
              r.modelDir.empty() ? "not found" : r.modelDir.c_str());
  for (const SelftestCheck& c : r.modelChecks) printCheck(c);
  if (r.validation)
    std::printf("validation layer: on, %zu message%s\n", r.validationMessages, r.validationMessages == 1 ? "" : "s");
  else
    std::printf("validation layer: %s\n", r.validationNote.c_str());
  std::printf("verdict: %s (%zu of %zu checks passed%s)\n", r.ok() ? "PASS" : "FAIL", r.passed(), r.total(),
              r.validationMessages ? ", validation messages" : "");
}

// Every device's self-test, one after another: a device that cannot be used is a failed column,
// not the end of the run.
std::vector<SelftestReport> runOnEveryDevice(const SelftestArgs& args) {
  std::vector<SelftestReport> reports;
  for (const std::string& name : Context::deviceNames(true)) {
    if (!args.json) std::fprintf(stderr, "spar selftest: %s\n", name.c_str());
    try {
      reports.push_back(runSelftestOn(name, args.model));
    } catch (const std::exception& e) {
      SelftestReport failed;
      failed.device = name;
      failed.error = e.what();
      reports.push_back(std::move(failed));
    }
  }
  return reports;
}

}  // namespace

bool runSelftest(const SelftestArgs& args) {
  if (!args.junit.empty()) checkJunitWritable(args.junit);  // before any work
  std::vector<SelftestReport> reports;
  if (args.allDevices)
    reports = runOnEveryDevice(args);
  else
    reports.push_back(runSelftestOn(args.device, args.model));
  bool ok = !reports.empty();
  for (const SelftestReport& r : reports) ok = ok && r.ok();
  if (!args.junit.empty()) writeSelftestJunit(args.junit, reports);
  if (args.json) {
    if (!args.allDevices) {
      std::cout << reportJson(reports[0]).dump(1) << "\n";
      return ok;
    }
    nlohmann::ordered_json doc = {{"devices", nlohmann::ordered_json::array()}, {"passed", ok}};
    for (const SelftestReport& r : reports) doc["devices"].push_back(reportJson(r));
    std::cout << doc.dump(1) << "\n";
    return ok;
  }
  if (args.allDevices)
    printDeviceTable(reports);
  else
    printReport(reports[0]);
  return ok;
}

}  // namespace spar::cli
