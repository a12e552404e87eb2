// DeviceLimits (include/spar/device_limits.h): the named profiles and their JSON form. How a
// profile tightens what the engine reads off the device: engine/device_limits.cpp.
// Every value of a named profile is cited in docs/portability.md's "Device-limit profiles" table.
#include "spar/device_limits.h"

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <limits>
#include <type_traits>
#include <nlohmann/json.hpp>

#include "spar/error.h"

namespace spar {
namespace {

constexpr uint64_t MiB = 1ull << 20;

// The Vulkan 1.2 specification's required limits ("Required Limits" table) and none of the
// optional features the engine can use.
DeviceLimits vulkanMinimum() {
  DeviceLimits l;
  l.name = "vulkan-1.2-min";
  l.maxTexelBufferElements = 65536;
  l.maxStorageBufferRange = 1ull << 27;
  l.maxMemoryAllocationSize = 1ull << 30;  // maintenance3, required minimum
  l.maxComputeSharedMemorySize = 16384;
  l.maxComputeWorkGroupInvocations = 128;
  l.maxComputeWorkGroupCount = 65535;
  l.maxPushConstantsSize = 128;
  l.maxPerStageDescriptorStorageBuffers = 4;
  l.maxPerStageDescriptorSampledImages = 16;
  l.minStorageBufferOffsetAlignment = 256;
  l.minTexelBufferOffsetAlignment = 256;
  l.shaderFloat16 = false;
  l.storageBuffer16BitAccess = false;
  l.subgroupArithmetic = false;
  l.cooperativeMatrix = false;
  l.subgroupSizeControl = false;
  return l;
}

std::vector<DeviceLimits> profiles() {
  std::vector<DeviceLimits> all;
  all.push_back(vulkanMinimum());

  // Khronos Vulkan-Profiles profiles/VP_ANDROID_baseline_2022.json: the same limits as the
  // specification's minimum (texel 65536, storage 2^27, shared 16384, 128 invocations, push 128,
  // 4 storage buffers, alignments 256); no fp16 or subgroup features listed.
  DeviceLimits android = vulkanMinimum();
  android.name = "android-baseline-2022";
  all.push_back(android);

  // Raspberry Pi 5, V3D 7.1 with Mesa 25.0.7's v3dv (a published vulkaninfo report; Mesa's
  // src/broadcom/vulkan/v3dv_device.c): 16 KiB shared memory, 256 invocations, 8 storage
  // buffers, push 128, storage alignment 32, texel 64, 1 GiB allocations, no fp16 arithmetic,
  // no subgroup arithmetic (size 16); the heap is half the RAM of a 4 GB board.
  DeviceLimits pi;
  pi.name = "raspberry-pi-5";
  pi.maxTexelBufferElements = 1ull << 28;
  pi.maxStorageBufferRange = 1ull << 30;
  pi.maxMemoryAllocationSize = 1ull << 30;
  pi.maxComputeSharedMemorySize = 16384;
  pi.maxComputeWorkGroupInvocations = 256;
  pi.maxComputeWorkGroupCount = 65535;
  pi.maxPushConstantsSize = 128;
  pi.maxPerStageDescriptorStorageBuffers = 8;
  pi.maxPerStageDescriptorSampledImages = 16;
  pi.minStorageBufferOffsetAlignment = 32;
  pi.minTexelBufferOffsetAlignment = 64;
  pi.shaderFloat16 = false;
  pi.subgroupArithmetic = false;
  pi.cooperativeMatrix = false;
  pi.deviceMemoryBytes = 2048 * MiB;
  all.push_back(pi);

  // A Mali-class GPU: Mali-G610 under Mesa's panvk (src/panfrost/vulkan/panvk_vX_physical_device.c):
  // 32 KiB shared memory, push 256, alignments 16, fp16 arithmetic and storage, subgroup
  // arithmetic (size 16). Its invocation limit is a hardware register: 256 assumed here; its
  // memory (a 4 GB board) assumed 2 GiB.
  DeviceLimits mali;
  mali.name = "mali-g610";
  mali.maxTexelBufferElements = 1ull << 27;
  mali.maxComputeSharedMemorySize = 32768;
  mali.maxComputeWorkGroupInvocations = 256;
  mali.maxComputeWorkGroupCount = 65535;
  mali.maxPushConstantsSize = 256;
  mali.minStorageBufferOffsetAlignment = 16;
  mali.minTexelBufferOffsetAlignment = 16;
  mali.cooperativeMatrix = false;
  mali.deviceMemoryBytes = 2048 * MiB;
  all.push_back(mali);

  // An Adreno-class GPU: Adreno 610 under Mesa's turnip (src/freedreno/vulkan/tu_device.cc,
  // tu_common.h, freedreno_devices.py): texel 2^27, storage 2^27, 16 KiB shared memory, 1024
  // invocations, push 256, texel alignment 64, fp16 arithmetic but no 16-bit storage, subgroup
  // arithmetic (size 64); memory (a 4 GB phone) assumed 2 GiB.
  DeviceLimits adreno;
  adreno.name = "adreno-610";
  adreno.maxTexelBufferElements = 1ull << 27;
  adreno.maxStorageBufferRange = 1ull << 27;
  adreno.maxComputeSharedMemorySize = 16384;
  adreno.maxComputeWorkGroupInvocations = 1024;
  adreno.maxComputeWorkGroupCount = 65535;
  adreno.maxPushConstantsSize = 256;
  adreno.minStorageBufferOffsetAlignment = 4;
  adreno.minTexelBufferOffsetAlignment = 64;
  adreno.storageBuffer16BitAccess = false;
  adreno.cooperativeMatrix = false;
  adreno.deviceMemoryBytes = 2048 * MiB;
  all.push_back(adreno);
  return all;
}

std::string bytesText(uint64_t b) {
  char t[32];
  if (b >= MiB && b % MiB == 0)
    std::snprintf(t, sizeof t, "%llu MiB", (unsigned long long)(b / MiB));
  else
    std::snprintf(t, sizeof t, "%llu B", (unsigned long long)b);
  return t;
}

}  // namespace

bool DeviceLimits::empty() const { return describe() == name + ":"; }

std::string DeviceLimits::describe() const {
  std::string s = name + ":";
  auto add = [&](const char* what, const std::string& value) { s += std::string(s.back() == ':' ? " " : ", ") + what + " " + value; };
  auto num = [&](const char* what, const auto& v) { if (v) add(what, std::to_string(*v)); };
  auto bytes = [&](const char* what, const std::optional<uint64_t>& v) { if (v) add(what, bytesText(*v)); };
  auto feature = [&](const char* what, const std::optional<bool>& v) { if (v) add(what, *v ? "yes" : "no"); };
  num("texel-buffer elements", maxTexelBufferElements);
  bytes("storage binding", maxStorageBufferRange);
  bytes("allocation", maxMemoryAllocationSize);
  num("shared memory", maxComputeSharedMemorySize);
  num("invocations", maxComputeWorkGroupInvocations);
  num("workgroups a dimension", maxComputeWorkGroupCount);
  num("push constants", maxPushConstantsSize);
  num("storage buffers a stage", maxPerStageDescriptorStorageBuffers);
  num("texel buffers a stage", maxPerStageDescriptorSampledImages);
  num("storage alignment", minStorageBufferOffsetAlignment);
  num("texel alignment", minTexelBufferOffsetAlignment);
  feature("fp16 arithmetic", shaderFloat16);
  feature("fp16 storage", storageBuffer16BitAccess);
  feature("subgroup arithmetic", subgroupArithmetic);
  feature("cooperative matrices", cooperativeMatrix);
  feature("subgroup size control", subgroupSizeControl);
  bytes("memory", deviceMemoryBytes);
  return s;
}

std::vector<std::string> DeviceLimits::profileNames() {
  std::vector<std::string> names;
  for (const DeviceLimits& p : profiles()) names.push_back(p.name);
  return names;
}

DeviceLimits DeviceLimits::profile(const std::string& name) {
  std::string known;
  for (const DeviceLimits& p : profiles()) {
    if (p.name == name) return p;
    known += (known.empty() ? "" : ", ") + p.name;
  }
  throw Error("unknown device-limit profile '" + name + "' (known: " + known + ", or a JSON file)");
}

DeviceLimits DeviceLimits::fromJsonFile(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw Error("device limits: cannot read " + path);
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(in);
  } catch (const std::exception& e) {
    throw Error("device limits: " + path + " is not JSON: " + std::string(e.what()).substr(0, std::string(e.what()).find('\n')));
  }
  if (!j.is_object()) throw Error("device limits: " + path + " must hold a JSON object");
  DeviceLimits l;
  l.name = path;
  for (const auto& item : j.items()) {
    // named references, not a structured binding: lambdas capture them (clang before 16 cannot
    // capture a binding)
    const std::string& key = item.key();
    const nlohmann::json& value = item.value();
    auto field = [&](const char* n) { return key == n; };
    auto count = [&](auto& slot) {
      using T = typename std::remove_reference_t<decltype(slot)>::value_type;
      if (!value.is_number_unsigned() || value.get<uint64_t>() == 0 ||
          value.get<uint64_t>() > uint64_t(std::numeric_limits<T>::max()))
        throw Error("device limits: " + path + ": " + key + " must be a positive integer");
      slot = value.get<T>();
    };
    auto flag = [&](std::optional<bool>& slot) {
      if (!value.is_boolean()) throw Error("device limits: " + path + ": " + key + " must be true or false");
      slot = value.get<bool>();
    };
    if (field("name")) {
      if (!value.is_string()) throw Error("device limits: " + path + ": name must be a string");
      l.name = value.get<std::string>();
    } else if (field("maxTexelBufferElements")) count(l.maxTexelBufferElements);
    else if (field("maxStorageBufferRange")) count(l.maxStorageBufferRange);
    else if (field("maxMemoryAllocationSize")) count(l.maxMemoryAllocationSize);
    else if (field("maxComputeSharedMemorySize")) count(l.maxComputeSharedMemorySize);
    else if (field("maxComputeWorkGroupInvocations")) count(l.maxComputeWorkGroupInvocations);
    else if (field("maxComputeWorkGroupCount")) count(l.maxComputeWorkGroupCount);
    else if (field("maxPushConstantsSize")) count(l.maxPushConstantsSize);
    else if (field("maxPerStageDescriptorStorageBuffers")) count(l.maxPerStageDescriptorStorageBuffers);
    else if (field("maxPerStageDescriptorSampledImages")) count(l.maxPerStageDescriptorSampledImages);
    else if (field("minStorageBufferOffsetAlignment")) count(l.minStorageBufferOffsetAlignment);
    else if (field("minTexelBufferOffsetAlignment")) count(l.minTexelBufferOffsetAlignment);
    else if (field("shaderFloat16")) flag(l.shaderFloat16);
    else if (field("storageBuffer16BitAccess")) flag(l.storageBuffer16BitAccess);
    else if (field("subgroupArithmetic")) flag(l.subgroupArithmetic);
    else if (field("cooperativeMatrix")) flag(l.cooperativeMatrix);
    else if (field("subgroupSizeControl")) flag(l.subgroupSizeControl);
    else if (field("deviceMemoryBytes")) count(l.deviceMemoryBytes);
    else throw Error("device limits: " + path + ": unknown field '" + key + "'");
  }
  for (const auto& a : {l.minStorageBufferOffsetAlignment, l.minTexelBufferOffsetAlignment})
    if (a && (*a & (*a - 1))) throw Error("device limits: " + path + ": alignments must be powers of two");
  return l;
}

DeviceLimits DeviceLimits::parse(const std::string& nameOrPath) {
  for (const std::string& n : profileNames())
    if (n == nameOrPath) return profile(n);
  if (nameOrPath.find('/') == std::string::npos && nameOrPath.find(".json") == std::string::npos)
    return profile(nameOrPath);  // not a path: the unknown-name error, which lists the names
  return fromJsonFile(nameOrPath);
}

}  // namespace spar
