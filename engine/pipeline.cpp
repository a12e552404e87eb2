#include "engine/pipeline.h"

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>

#include "engine/error.h"
#include "engine/shader_registry.h"

namespace spar {
namespace {

std::string keyOf(const KernelSpec& spec) {
  std::string key = spec.shader + "|";
  for (auto b : spec.bindings) key += static_cast<char>('0' + static_cast<int>(b));
  key += "|" + std::to_string(spec.pushBytes) + "|";
  for (auto c : spec.constants) key += std::to_string(c) + ",";
  return key;
}

VkDescriptorType descriptorType(Bind b) {
  return b == Bind::Texel ? VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER : VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
}

}  // namespace

PipelineCache::PipelineCache(Device& device, std::string cacheFile) : device_(device), cacheFile_(std::move(cacheFile)) {
  std::vector<char> initial;
  if (!cacheFile_.empty()) {
    std::ifstream in(cacheFile_, std::ios::binary);
    if (in) initial.assign(std::istreambuf_iterator<char>(in), {});
  }
  VkPipelineCacheCreateInfo info{VK_STRUCTURE_TYPE_PIPELINE_CACHE_CREATE_INFO};
  info.initialDataSize = initial.size();
  info.pInitialData = initial.empty() ? nullptr : initial.data();
  // A stale or foreign cache file is ignored by the driver; if it is refused outright, start empty.
  if (vkCreatePipelineCache(device_.handle(), &info, nullptr, &driverCache_) != VK_SUCCESS) {
    info.initialDataSize = 0;
    info.pInitialData = nullptr;
    SPAR_VK(vkCreatePipelineCache(device_.handle(), &info, nullptr, &driverCache_));
  }
}

PipelineCache::~PipelineCache() {
  VkDevice dev = device_.handle();
  if (!cacheFile_.empty()) {
    size_t size = 0;
    if (vkGetPipelineCacheData(dev, driverCache_, &size, nullptr) == VK_SUCCESS && size) {
      std::vector<char> data(size);
      if (vkGetPipelineCacheData(dev, driverCache_, &size, data.data()) == VK_SUCCESS) {
        std::string tmp = cacheFile_ + ".tmp";
        std::ofstream out(tmp, std::ios::binary);
        out.write(data.data(), static_cast<std::streamsize>(size));
        out.close();
        if (out) std::rename(tmp.c_str(), cacheFile_.c_str());
      }
    }
  }
  for (auto& [key, k] : kernels_) {
    vkDestroyPipeline(dev, k->pipeline, nullptr);
    vkDestroyPipelineLayout(dev, k->layout, nullptr);
    vkDestroyDescriptorSetLayout(dev, k->setLayout, nullptr);
  }
  vkDestroyPipelineCache(dev, driverCache_, nullptr);
}

const Kernel& PipelineCache::get(const KernelSpec& spec) {
  const std::string key = keyOf(spec);
  if (auto it = kernels_.find(key); it != kernels_.end()) return *it->second;
  if (spec.constants.size() < 3) throw Error("kernel " + spec.shader + ": constants 0-2 must give the workgroup size");
  if (spec.pushBytes > device_.caps().maxPushConstantsSize)
    throw Error("kernel " + spec.shader + " needs more push-constant bytes than the device offers");

  VkDevice dev = device_.handle();
  auto kernel = std::make_unique<Kernel>();
  kernel->name = spec.shader;
  kernel->bindings = spec.bindings;
  kernel->pushBytes = spec.pushBytes;
  for (int i = 0; i < 3; ++i) kernel->localSize[i] = static_cast<uint32_t>(spec.constants[i]);
  if (kernel->localSize[0] * kernel->localSize[1] * kernel->localSize[2] > device_.caps().maxWorkGroupInvocations)
    throw Error("kernel " + spec.shader + ": workgroup larger than the device allows");

  std::vector<VkDescriptorSetLayoutBinding> bindings;
  for (uint32_t i = 0; i < spec.bindings.size(); ++i)
    bindings.push_back({i, descriptorType(spec.bindings[i]), 1, VK_SHADER_STAGE_COMPUTE_BIT, nullptr});
  VkDescriptorSetLayoutCreateInfo setInfo{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
  setInfo.bindingCount = static_cast<uint32_t>(bindings.size());
  setInfo.pBindings = bindings.data();
  SPAR_VK(vkCreateDescriptorSetLayout(dev, &setInfo, nullptr, &kernel->setLayout));

  VkPushConstantRange push{VK_SHADER_STAGE_COMPUTE_BIT, 0, spec.pushBytes};
  VkPipelineLayoutCreateInfo layoutInfo{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
  layoutInfo.setLayoutCount = 1;
  layoutInfo.pSetLayouts = &kernel->setLayout;
  layoutInfo.pushConstantRangeCount = spec.pushBytes ? 1 : 0;
  layoutInfo.pPushConstantRanges = spec.pushBytes ? &push : nullptr;
  SPAR_VK(vkCreatePipelineLayout(dev, &layoutInfo, nullptr, &kernel->layout));

  auto words = findShader(spec.shader);
  VkShaderModuleCreateInfo moduleInfo{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
  moduleInfo.codeSize = words.size() * sizeof(uint32_t);
  moduleInfo.pCode = words.data();
  VkShaderModule module = VK_NULL_HANDLE;
  SPAR_VK(vkCreateShaderModule(dev, &moduleInfo, nullptr, &module));

  std::vector<VkSpecializationMapEntry> entries;
  for (uint32_t i = 0; i < spec.constants.size(); ++i)
    entries.push_back({i, static_cast<uint32_t>(i * sizeof(int32_t)), sizeof(int32_t)});
  VkSpecializationInfo specInfo{};
  specInfo.mapEntryCount = static_cast<uint32_t>(entries.size());
  specInfo.pMapEntries = entries.data();
  specInfo.dataSize = spec.constants.size() * sizeof(int32_t);
  specInfo.pData = spec.constants.data();

  VkComputePipelineCreateInfo info{VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO};
  info.stage = {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO};
  info.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
  info.stage.module = module;
  info.stage.pName = "main";
  info.stage.pSpecializationInfo = &specInfo;
  info.layout = kernel->layout;
  const auto t0 = std::chrono::steady_clock::now();
  VkResult r = vkCreateComputePipelines(dev, driverCache_, 1, &info, nullptr, &kernel->pipeline);
  vkDestroyShaderModule(dev, module, nullptr);
  vkCheck(r, ("creating the pipeline of " + spec.shader).c_str());

  for (size_t i = 3; i < spec.constants.size(); ++i)
    kernel->name += (i == 3 ? "<" : ",") + std::to_string(spec.constants[i]);
  if (spec.constants.size() > 3) kernel->name += ">";
  // Pipeline creation is where a JIT driver (lavapipe) compiles: SPAR_LOG_PIPELINES=1 shows
  // what each variant costs at start-up.
  if (const char* log = std::getenv("SPAR_LOG_PIPELINES"); log && std::string(log) == "1") {
    const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    std::fprintf(stderr, "pipeline %s: %.0f ms\n", kernel->name.c_str(), ms);
  }
  return *(kernels_[key] = std::move(kernel));
}

}  // namespace spar
