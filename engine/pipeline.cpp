#include "engine/pipeline.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <string>
#include <thread>

#include <unistd.h>

#include "engine/vk_result.h"
#include "engine/shader_registry.h"
#include "engine/spirv_freeze.h"

namespace spar {
namespace {

std::string keyOf(const KernelSpec& spec) {
  std::string key = spec.shader + "|";
  for (auto b : spec.bindings) key += static_cast<char>('0' + static_cast<int>(b));
  key += "|" + std::to_string(spec.pushBytes) + "|";
  for (auto c : spec.constants) key += std::to_string(c) + ",";
  if (spec.subgroupSize) key += "|sg" + std::to_string(spec.subgroupSize);
  if (spec.freezeConstants) key += "|frozen";
  return key;
}

VkDescriptorType descriptorType(Bind b) {
  return b == Bind::Texel ? VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER : VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
}

// The fp16 bits of a storage-input twin (kStorageInputF16ConstantId): the signature's i-th
// entry is the format of the kernel's i-th StorageInput binding.
int32_t storageInputF16Bits(const Kernel& kernel, const std::string& signature) {
  int32_t bits = 0;
  size_t entry = 0;
  for (size_t b = 0; b < kernel.bindings.size(); ++b) {
    if (kernel.bindings[b] != Bind::StorageInput) continue;
    if (signature.compare(entry, 3, "f16") == 0) bits |= int32_t(1) << b;
    entry = signature.find(',', entry);
    if (entry == std::string::npos) break;
    ++entry;
  }
  return bits;
}

// The signature is only worth a name when it is not all f32.
std::string pipelineName(const Kernel& kernel, const std::string& signature) {
  bool allF32 = true;
  for (size_t i = 0; i < signature.size(); i += 6) allF32 = allF32 && signature.compare(i, 3, "f32") == 0;
  return allF32 ? kernel.name : kernel.name + "{" + signature + "}";
}

}  // namespace

PipelineCache::PipelineCache(Device& device, std::string cacheFile, bool log)
    : device_(device), cacheFile_(std::move(cacheFile)), log_(log) {
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
        // A temporary of this process's own: two processes saving the shared cache at once
        // (spar jobs, tests run in parallel) each rename a whole file; the last one stays.
        const std::string tmp = cacheFile_ + ".tmp-" + std::to_string(::getpid());
        std::ofstream out(tmp, std::ios::binary);
        out.write(data.data(), static_cast<std::streamsize>(size));
        out.close();
        if (out) std::rename(tmp.c_str(), cacheFile_.c_str());
      }
    }
  }
  for (auto& [key, p] : pipelines_) vkDestroyPipeline(dev, p->handle, nullptr);
  for (auto& [key, k] : kernels_) {
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
  const auto texels = std::count(spec.bindings.begin(), spec.bindings.end(), Bind::Texel);
  const auto storage = static_cast<std::ptrdiff_t>(spec.bindings.size()) - texels;
  if (uint64_t(storage) > device_.caps().maxPerStageStorageBuffers || uint64_t(texels) > device_.caps().maxPerStageSampledImages)
    throw Error("kernel " + spec.shader + " binds " + std::to_string(storage) + " storage and " + std::to_string(texels) +
                " texel buffers; the device allows " + std::to_string(device_.caps().maxPerStageStorageBuffers) + " and " +
                std::to_string(device_.caps().maxPerStageSampledImages));
  findShader(spec.shader);  // an unknown variant fails here, where the op asks for it

  VkDevice dev = device_.handle();
  auto kernel = std::make_unique<Kernel>();
  kernel->name = spec.shader;
  kernel->spec = spec;
  kernel->bindings = spec.bindings;
  kernel->pushBytes = spec.pushBytes;
  kernel->storageInputs = std::count(spec.bindings.begin(), spec.bindings.end(), Bind::StorageInput) > 0;
  for (int i = 0; i < 3; ++i) kernel->localSize[i] = static_cast<uint32_t>(spec.constants[i]);
  if (kernel->localSize[0] * kernel->localSize[1] * kernel->localSize[2] > device_.caps().maxWorkGroupInvocations)
    throw Error("kernel " + spec.shader + ": workgroup larger than the device allows");
  for (size_t i = 3; i < spec.constants.size(); ++i)
    kernel->name += (i == 3 ? "<" : ",") + std::to_string(spec.constants[i]);
  if (spec.constants.size() > 3) kernel->name += ">";
  kernel->name += "[" + std::to_string(spec.constants[0]) + "x" + std::to_string(spec.constants[1]) + "x" +
                  std::to_string(spec.constants[2]) + "]";

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
  VkResult r = vkCreatePipelineLayout(dev, &layoutInfo, nullptr, &kernel->layout);
  if (r != VK_SUCCESS) {
    vkDestroyDescriptorSetLayout(dev, kernel->setLayout, nullptr);
    vkCheck(r, "vkCreatePipelineLayout");
  }
  return *(kernels_[key] = std::move(kernel));
}

VkPipeline PipelineCache::build(const Kernel& kernel, const std::string& signature, double* ms) {
  VkDevice dev = device_.handle();
  const DeviceCaps& caps = device_.caps();
  if (kernel.spec.subgroupSize && !caps.fullSubgroups)
    throw Error("kernel " + kernel.name + " needs full subgroups (VK_EXT_subgroup_size_control)");
  std::vector<int32_t> constants = kernel.spec.constants;
  std::vector<VkSpecializationMapEntry> entries;
  for (uint32_t i = 0; i < constants.size(); ++i)
    entries.push_back({i, static_cast<uint32_t>(i * sizeof(int32_t)), sizeof(int32_t)});
  if (kernel.storageInputs) {
    if (constants.size() > kStorageInputF16ConstantId)
      throw Error("kernel " + kernel.name + ": constant ids reach the storage-input id");
    entries.push_back({kStorageInputF16ConstantId, static_cast<uint32_t>(constants.size() * sizeof(int32_t)), sizeof(int32_t)});
    constants.push_back(storageInputF16Bits(kernel, signature));
  }

  const auto words = findShader(kernel.spec.shader);
  std::vector<uint32_t> frozen;
  if (kernel.spec.freezeConstants) {  // the values go into the module itself (engine/spirv_freeze.h)
    std::vector<std::pair<uint32_t, uint32_t>> values;
    for (const auto& e : entries) values.push_back({e.constantID, static_cast<uint32_t>(constants[e.offset / sizeof(int32_t)])});
    frozen = freezeSpecConstants(words, values);
  }
  VkShaderModuleCreateInfo moduleInfo{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
  moduleInfo.codeSize = (kernel.spec.freezeConstants ? frozen.size() : words.size()) * sizeof(uint32_t);
  moduleInfo.pCode = kernel.spec.freezeConstants ? frozen.data() : words.data();
  VkShaderModule module = VK_NULL_HANDLE;
  SPAR_VK(vkCreateShaderModule(dev, &moduleInfo, nullptr, &module));
  VkSpecializationInfo specInfo{};
  specInfo.mapEntryCount = static_cast<uint32_t>(entries.size());
  specInfo.pMapEntries = entries.data();
  specInfo.dataSize = constants.size() * sizeof(int32_t);
  specInfo.pData = constants.data();

  VkComputePipelineCreateInfo info{VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO};
  info.stage = {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO};
  info.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
  info.stage.module = module;
  info.stage.pName = "main";
  info.stage.pSpecializationInfo = kernel.spec.freezeConstants ? nullptr : &specInfo;
  VkPipelineShaderStageRequiredSubgroupSizeCreateInfoEXT requiredSize{
      VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_REQUIRED_SUBGROUP_SIZE_CREATE_INFO_EXT};
  if (kernel.spec.subgroupSize) {
    info.stage.flags = VK_PIPELINE_SHADER_STAGE_CREATE_REQUIRE_FULL_SUBGROUPS_BIT_EXT;
    if (caps.requiredSubgroupSize && caps.minSubgroupSize != caps.maxSubgroupSize) {
      requiredSize.requiredSubgroupSize = kernel.spec.subgroupSize;
      info.stage.pNext = &requiredSize;
    }
  }
  info.layout = kernel.layout;
  VkPipeline pipeline = VK_NULL_HANDLE;
  const auto t0 = std::chrono::steady_clock::now();
  VkResult r = vkCreateComputePipelines(dev, driverCache_, 1, &info, nullptr, &pipeline);
  *ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  vkDestroyShaderModule(dev, module, nullptr);
  vkCheck(r, ("creating the pipeline of " + kernel.name).c_str());
  return pipeline;
}

Pipeline* PipelineCache::find(const Kernel& kernel, const std::string& signature) {
  auto it = pipelines_.find({&kernel, signature});
  return it == pipelines_.end() ? nullptr : it->second.get();
}

Pipeline& PipelineCache::pipeline(const Kernel& kernel, const std::string& signature) {
  if (Pipeline* p = find(kernel, signature)) return *p;
  create({{&kernel, signature}});
  return *find(kernel, signature);
}

void PipelineCache::create(const std::vector<std::pair<const Kernel*, std::string>>& wanted) {
  std::vector<std::unique_ptr<Pipeline>> fresh;
  for (const auto& [kernel, signature] : wanted) {
    if (find(*kernel, signature)) continue;
    bool listed = false;
    for (const auto& f : fresh) listed = listed || (f->kernel == kernel && f->signature == signature);
    if (listed) continue;
    auto p = std::make_unique<Pipeline>();
    p->kernel = kernel;
    p->signature = signature;
    p->name = pipelineName(*kernel, signature);
    fresh.push_back(std::move(p));
  }
  if (fresh.empty()) return;

  // Pipelines are independent: create them from a few threads at once. A failure is kept
  // and rethrown after every thread is done, so no half-made pipeline is left behind.
  std::vector<std::string> errors(fresh.size());
  std::atomic<size_t> next{0};
  auto work = [&] {
    for (size_t i; (i = next++) < fresh.size();) {
      try {
        fresh[i]->handle = build(*fresh[i]->kernel, fresh[i]->signature, &fresh[i]->stats.createMs);
      } catch (const std::exception& e) {
        errors[i] = e.what();
      }
    }
  };
  const size_t threads = std::min<size_t>(fresh.size(), std::max(1u, std::thread::hardware_concurrency()));
  std::vector<std::thread> pool;
  for (size_t t = 1; t < threads; ++t) pool.emplace_back(work);
  work();
  for (auto& t : pool) t.join();

  std::string firstError;
  for (size_t i = 0; i < fresh.size(); ++i) {
    if (!errors[i].empty()) {
      if (firstError.empty()) firstError = errors[i];
      continue;
    }
    if (log_)
      std::fprintf(stderr, "pipeline %s: created in %.1f ms (texel formats %s)\n", fresh[i]->name.c_str(), fresh[i]->stats.createMs, fresh[i]->signature.empty() ? "none" : fresh[i]->signature.c_str());
    order_.push_back(fresh[i].get());
    auto key = std::make_pair(fresh[i]->kernel, fresh[i]->signature);
    pipelines_[key] = std::move(fresh[i]);
  }
  if (!firstError.empty()) throw Error(firstError);
}

std::vector<const Pipeline*> PipelineCache::pipelines() const { return order_; }

PipelineTotals PipelineCache::totals() const {
  PipelineTotals t;
  for (const Pipeline* p : order_) {
    ++t.pipelines;
    t.createMs += p->stats.createMs;
    t.builds += p->stats.builds;
    t.compiles += p->stats.compiles;
    t.rebuilds += p->stats.rebuildCount();
    t.buildMs += p->stats.buildMs;
    t.dispatches += p->stats.dispatches;
    t.gpuMs += p->stats.gpuMs;
  }
  return t;
}

}  // namespace spar
