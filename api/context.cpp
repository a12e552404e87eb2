// spar::Context (include/spar/context.h): owns the engine, and reports on its device, kernels
// and memory in the public types.
#include "api/api_impl.h"
#include "engine/kernel_plan.h"
#include "engine/memory.h"
#include "engine/pipeline.h"

namespace spar {
namespace {

DeviceInfo deviceInfo(const DeviceCaps& c) {
  DeviceInfo d;
  d.name = c.name;
  d.driver = c.driverInfo;
  d.vulkanMajor = VK_API_VERSION_MAJOR(c.apiVersion);
  d.vulkanMinor = VK_API_VERSION_MINOR(c.apiVersion);
  d.limitsProfile = c.limitsProfile;
  d.maxTexelBufferElements = c.maxTexelBufferElements;
  d.maxStorageBufferRange = c.maxStorageBufferRange;
  d.maxComputeSharedMemorySize = c.maxSharedMemory;
  d.maxComputeWorkGroupInvocations = c.maxWorkGroupInvocations;
  d.maxPushConstantsSize = c.maxPushConstantsSize;
  d.maxPerStageStorageBuffers = c.maxPerStageStorageBuffers;
  d.maxPerStageTexelBuffers = c.maxPerStageSampledImages;
  d.minStorageBufferOffsetAlignment = c.minStorageBufferOffsetAlignment;
  d.minTexelBufferOffsetAlignment = c.minTexelBufferOffsetAlignment;
  d.shaderFloat16 = c.shaderFloat16;
  d.fp16Storage = c.supportsFp16Storage();
  d.subgroupSize = c.subgroupSize;
  d.subgroupArithmetic = c.subgroupArithmetic;
  d.cooperativeMatrix = c.cooperativeMatrix;
  d.hostVisibleDeviceLocal = c.hostVisibleDeviceLocal;
  return d;
}

KernelStats kernelStats(const Pipeline& p) {
  const PipelineStats& s = p.stats;
  KernelStats k;
  k.name = p.name;
  k.texelFormats = p.signature;
  k.createMs = s.createMs;
  k.builds = uint64_t(s.builds);
  k.compiles = uint64_t(s.compiles);
  k.buildMs = s.buildMs;
  k.dispatches = uint64_t(s.dispatches);
  k.texelStates = s.texelStates.size();
  k.gpuMs = s.gpuMs;
  for (int c = 1; c < 4; ++c)
    if (s.rebuilds[c]) k.rebuildCauses[buildCauseName(static_cast<BuildCause>(c))] = uint64_t(s.rebuilds[c]);
  return k;
}

}  // namespace

Context::Context(const EngineOptions& options) : impl_(std::make_unique<Impl>(options)) {}
Context::~Context() = default;

std::vector<std::string> Context::listDevices() { return Device::listDevices(); }
std::vector<std::string> Context::deviceNames(bool extraDrivers) { return Device::deviceNames(extraDrivers); }

std::string Context::deviceName() const { return impl_->engine.caps().name; }
DeviceInfo Context::device() const { return deviceInfo(impl_->engine.caps()); }
const EngineOptions& Context::options() const { return impl_->engine.options(); }

uint64_t Context::validationMessages() const { return impl_->engine.device().validationMessageCount(); }

std::vector<std::string> Context::kernelPlan() {
  Engine& e = impl_->engine;
  return describePlan(e.plan(), e.caps());
}

KernelReport Context::kernelReport() {
  KernelReport r;
  r.plan = kernelPlan();
  const PipelineCache& cache = impl_->engine.pipelines();
  const PipelineTotals t = cache.totals();
  r.pipelines = uint64_t(t.pipelines);
  r.createMs = t.createMs;
  r.builds = uint64_t(t.builds);
  r.compiles = uint64_t(t.compiles);
  r.rebuilds = uint64_t(t.rebuilds);
  r.buildMs = t.buildMs;
  r.dispatches = uint64_t(t.dispatches);
  r.computeMs = t.gpuMs;
  for (const Pipeline* p : cache.pipelines()) r.kernels.push_back(kernelStats(*p));
  return r;
}

MemoryStats Context::memory() const {
  Engine& e = impl_->engine;
  MemoryStats m;
  m.bytesInUse = e.memory().bytesInUse();
  m.peakBytes = e.memory().peakBytes();
  m.budgetBytes = e.memory().budget();
  m.budgetSource = e.memory().budgetSource();
  m.allocations = e.memory().allocations();
  m.submissions = e.submissions();
  return m;
}

}  // namespace spar
