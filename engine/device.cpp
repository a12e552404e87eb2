#include "engine/device.h"

#include "engine/device_limits.h"

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <cstring>
#include <iostream>

#include "engine/coopmat_khr.h"
#include "engine/vk_result.h"
#include "engine/extra_drivers.h"

namespace spar {
namespace {

const char* kValidationLayer = "VK_LAYER_KHRONOS_validation";

VKAPI_ATTR VkBool32 VKAPI_CALL onValidationMessage(VkDebugUtilsMessageSeverityFlagBitsEXT severity,
                                                   VkDebugUtilsMessageTypeFlagsEXT,
                                                   const VkDebugUtilsMessengerCallbackDataEXT* data,
                                                   void* user) {
  if (severity >= VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT) {
    std::string text = data && data->pMessage ? data->pMessage : "(no message)";
    std::cerr << "[vulkan validation] " << text << "\n";
    static_cast<Device*>(user)->recordValidationMessage(text);
  }
  return VK_FALSE;
}

const char* typeName(VkPhysicalDeviceType type) {
  switch (type) {
    case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU: return "discrete GPU";
    case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU: return "integrated GPU";
    case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU: return "virtual GPU";
    case VK_PHYSICAL_DEVICE_TYPE_CPU: return "CPU";
    default: return "other";
  }
}

int typePreference(VkPhysicalDeviceType type) {
  switch (type) {
    case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU: return 0;
    case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU: return 1;
    case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU: return 2;
    case VK_PHYSICAL_DEVICE_TYPE_CPU: return 3;
    default: return 4;
  }
}

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

// `select` (DeviceOptions::select): the drivers outside the loader's paths that it names join
// this instance (extra_drivers.h).
VkInstance createBareInstance(bool validation, bool debugUtils, const std::string& select) {
  const ScopedExtraDrivers extra(extraDriverManifests(select));
  VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO};
  app.pApplicationName = "spar";
  app.pEngineName = "spar-vulkan";
  app.apiVersion = VK_API_VERSION_1_2;
  std::vector<const char*> layers, extensions;
  if (validation) layers.push_back(kValidationLayer);
  if (debugUtils) extensions.push_back(VK_EXT_DEBUG_UTILS_EXTENSION_NAME);
  // With validation, synchronization validation too: a missing or wrong barrier between
  // dispatches (a read-after-write hazard) is a message like any other.
  const VkValidationFeatureEnableEXT enables[] = {VK_VALIDATION_FEATURE_ENABLE_SYNCHRONIZATION_VALIDATION_EXT};
  VkValidationFeaturesEXT features{VK_STRUCTURE_TYPE_VALIDATION_FEATURES_EXT};
  features.enabledValidationFeatureCount = 1;
  features.pEnabledValidationFeatures = enables;
  if (validation) extensions.push_back(VK_EXT_VALIDATION_FEATURES_EXTENSION_NAME);
  VkInstanceCreateInfo info{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
  if (validation) info.pNext = &features;
  info.pApplicationInfo = &app;
  info.enabledLayerCount = static_cast<uint32_t>(layers.size());
  info.ppEnabledLayerNames = layers.data();
  info.enabledExtensionCount = static_cast<uint32_t>(extensions.size());
  info.ppEnabledExtensionNames = extensions.data();
  VkInstance instance = VK_NULL_HANDLE;
  SPAR_VK(vkCreateInstance(&info, nullptr, &instance));
  return instance;
}

std::vector<VkPhysicalDevice> physicalDevices(VkInstance instance) {
  uint32_t count = 0;
  SPAR_VK(vkEnumeratePhysicalDevices(instance, &count, nullptr));
  std::vector<VkPhysicalDevice> devices(count);
  SPAR_VK(vkEnumeratePhysicalDevices(instance, &count, devices.data()));
  if (devices.empty()) throw Error("no Vulkan device found (install mesa-vulkan-drivers for the CPU device lavapipe)");
  return devices;
}

bool layerAvailable(const char* name) {
  uint32_t count = 0;
  vkEnumerateInstanceLayerProperties(&count, nullptr);
  std::vector<VkLayerProperties> layers(count);
  vkEnumerateInstanceLayerProperties(&count, layers.data());
  for (const auto& l : layers)
    if (std::strcmp(l.layerName, name) == 0) return true;
  return false;
}

bool hasDeviceExtension(VkPhysicalDevice device, const char* name) {
  uint32_t count = 0;
  vkEnumerateDeviceExtensionProperties(device, nullptr, &count, nullptr);
  std::vector<VkExtensionProperties> exts(count);
  vkEnumerateDeviceExtensionProperties(device, nullptr, &count, exts.data());
  for (const auto& e : exts)
    if (std::strcmp(e.extensionName, name) == 0) return true;
  return false;
}

// The subgroup-scope sizes of VK_KHR_cooperative_matrix (empty without the extension).
std::vector<CoopMatSize> coopMatSizes(VkInstance instance, VkPhysicalDevice device) {
  auto get = reinterpret_cast<PFN_vkGetPhysicalDeviceCooperativeMatrixPropertiesKHR>(
      vkGetInstanceProcAddr(instance, "vkGetPhysicalDeviceCooperativeMatrixPropertiesKHR"));
  std::vector<CoopMatSize> out;
  if (!get) return out;
  uint32_t count = 0;
  if (get(device, &count, nullptr) != VK_SUCCESS || count == 0) return out;
  std::vector<VkCooperativeMatrixPropertiesKHR> props(count);
  for (auto& p : props) p = {VK_STRUCTURE_TYPE_COOPERATIVE_MATRIX_PROPERTIES_KHR};
  if (get(device, &count, props.data()) != VK_SUCCESS) return out;
  for (uint32_t i = 0; i < count; ++i) {
    const auto& p = props[i];
    if (p.scope != VK_SCOPE_SUBGROUP_KHR) continue;
    out.push_back({p.MSize, p.NSize, p.KSize, int(p.AType), int(p.BType), int(p.CType), int(p.ResultType)});
  }
  return out;
}

bool texelFormatSupported(VkPhysicalDevice device, VkFormat format) {
  VkFormatProperties props{};
  vkGetPhysicalDeviceFormatProperties(device, format, &props);
  return (props.bufferFeatures & VK_FORMAT_FEATURE_UNIFORM_TEXEL_BUFFER_BIT) != 0;
}

// Every device's properties, in the loader's order.
std::vector<VkPhysicalDeviceProperties> deviceProperties(bool extraDrivers) {
  VkInstance instance = createBareInstance(false, false, extraDrivers ? "*" : "");
  std::vector<VkPhysicalDeviceProperties> out;
  try {
    for (VkPhysicalDevice d : physicalDevices(instance)) {
      out.emplace_back();
      vkGetPhysicalDeviceProperties(d, &out.back());
    }
  } catch (...) {
    vkDestroyInstance(instance, nullptr);
    throw;
  }
  vkDestroyInstance(instance, nullptr);
  return out;
}

}  // namespace

std::vector<std::string> Device::listDevices(bool extraDrivers) {
  std::vector<std::string> out;
  const auto props = deviceProperties(extraDrivers);
  for (size_t i = 0; i < props.size(); ++i)
    out.push_back(std::to_string(i) + ": " + props[i].deviceName + " (" + typeName(props[i].deviceType) + ")");
  return out;
}

std::vector<std::string> Device::deviceNames(bool extraDrivers) {
  std::vector<std::string> out;
  for (const auto& p : deviceProperties(extraDrivers))
    if (std::find(out.begin(), out.end(), p.deviceName) == out.end()) out.push_back(p.deviceName);
  return out;
}

Device::Device(const DeviceOptions& options) {
  try {
    createInstance(options.validation, options.select);
    pickPhysicalDevice(options.select);
    readCaps();
    tightenCaps(caps_, options.limits);
    bindingRangeLimit_ = caps_.maxStorageBufferRange;
    createLogicalDevice();
  } catch (...) {
    if (device_) vkDestroyDevice(device_, nullptr);
    if (messenger_) {
      auto destroy = reinterpret_cast<PFN_vkDestroyDebugUtilsMessengerEXT>(
          vkGetInstanceProcAddr(instance_, "vkDestroyDebugUtilsMessengerEXT"));
      destroy(instance_, messenger_, nullptr);
    }
    if (instance_) vkDestroyInstance(instance_, nullptr);
    throw;
  }
  if (options.verbose) {
    std::cerr << "device: " << caps_.name << " (" << typeName(caps_.type) << ", Vulkan "
              << VK_API_VERSION_MAJOR(caps_.apiVersion) << "." << VK_API_VERSION_MINOR(caps_.apiVersion)
              << (caps_.driverInfo.empty() ? "" : ", " + caps_.driverInfo) << ")\n  features used: subgroup size " << caps_.subgroupSize
              << ", fp16 storage " << (caps_.supportsFp16Storage() ? "yes" : "no")
              << ", fp16 arithmetic " << (caps_.shaderFloat16 ? "yes" : "no")
              << ", cooperative matrices " << (caps_.cooperativeMatrix ? "yes" : "no")
              << ", timestamps " << (caps_.timestamps ? "yes" : "no")
              << ", host-visible device memory " << (caps_.hostVisibleDeviceLocal ? "yes" : "no (staging)")
              << ", max binding " << (caps_.maxStorageBufferRange >> 20) << " MiB"
              << (validationEnabled() ? ", validation layer on" : "")
              << (caps_.limitsProfile.empty() ? "" : "\n  device-limit profile " + options.limits.describe()) << "\n";
    if (caps_.shaderCacheIgnoresVectorWidth() && std::getenv("LP_NATIVE_VECTOR_WIDTH"))
      std::cerr << "  note: LP_NATIVE_VECTOR_WIDTH is set, and this Mesa's shader cache does not tell vector widths apart:"
                   " shaders built at another width run at its speed; give each width its own MESA_SHADER_CACHE_DIR\n";
  }
}

Device::~Device() {
  if (device_) {
    vkDeviceWaitIdle(device_);
    vkDestroyDevice(device_, nullptr);
  }
  if (messenger_) {
    auto destroy = reinterpret_cast<PFN_vkDestroyDebugUtilsMessengerEXT>(
        vkGetInstanceProcAddr(instance_, "vkDestroyDebugUtilsMessengerEXT"));
    destroy(instance_, messenger_, nullptr);
  }
  if (instance_) vkDestroyInstance(instance_, nullptr);
}

void Device::createInstance(bool validation, const std::string& select) {
  if (validation && !layerAvailable(kValidationLayer))
    throw Error("validation requested but VK_LAYER_KHRONOS_validation is not installed (apt-get install vulkan-validationlayers)");
  instance_ = createBareInstance(validation, validation, select);
  if (!validation) return;
  VkDebugUtilsMessengerCreateInfoEXT info{VK_STRUCTURE_TYPE_DEBUG_UTILS_MESSENGER_CREATE_INFO_EXT};
  info.messageSeverity = VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT | VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT;
  info.messageType = VK_DEBUG_UTILS_MESSAGE_TYPE_GENERAL_BIT_EXT | VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT |
                     VK_DEBUG_UTILS_MESSAGE_TYPE_PERFORMANCE_BIT_EXT;
  info.pfnUserCallback = onValidationMessage;
  info.pUserData = this;
  auto create = reinterpret_cast<PFN_vkCreateDebugUtilsMessengerEXT>(
      vkGetInstanceProcAddr(instance_, "vkCreateDebugUtilsMessengerEXT"));
  if (!create) throw Error("VK_EXT_debug_utils is not available for validation messages");
  SPAR_VK(create(instance_, &info, nullptr, &messenger_));
}

void Device::pickPhysicalDevice(const std::string& select) {
  auto devices = physicalDevices(instance_);
  std::vector<VkPhysicalDeviceProperties> props(devices.size());
  for (size_t i = 0; i < devices.size(); ++i) vkGetPhysicalDeviceProperties(devices[i], &props[i]);

  auto usable = [&](size_t i) { return props[i].apiVersion >= VK_API_VERSION_1_2; };
  if (!select.empty()) {
    bool numeric = std::all_of(select.begin(), select.end(), [](unsigned char c) { return std::isdigit(c); });
    for (size_t i = 0; i < devices.size(); ++i) {
      bool match = numeric ? std::to_string(i) == select
                           : lower(props[i].deviceName).find(lower(select)) != std::string::npos;
      if (!match) continue;
      if (!usable(i)) throw Error(std::string("device '") + props[i].deviceName + "' does not support Vulkan 1.2");
      physical_ = devices[i];
      return;
    }
    std::string names;
    for (size_t i = 0; i < devices.size(); ++i) names += (i ? ", " : "") + std::to_string(i) + ": " + props[i].deviceName;
    const std::string missing = missingExtraDriver(select);
    throw Error("no Vulkan device matches '" + select + "' (available: " + names + ")" +
                (missing.empty() ? "" : ": " + missing));
  }
  int best = -1;
  for (size_t i = 0; i < devices.size(); ++i) {
    if (!usable(i)) continue;
    if (best < 0 || typePreference(props[i].deviceType) < typePreference(props[best].deviceType)) best = static_cast<int>(i);
  }
  if (best < 0) throw Error("no Vulkan 1.2 device found");
  physical_ = devices[best];
}

void Device::readCaps() {
  VkPhysicalDeviceDriverProperties driver{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_DRIVER_PROPERTIES};
  VkPhysicalDeviceSubgroupProperties subgroup{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_PROPERTIES};
  subgroup.pNext = &driver;
  VkPhysicalDeviceSubgroupSizeControlPropertiesEXT sizeControl{
      VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_SIZE_CONTROL_PROPERTIES_EXT};
  const bool hasSizeControl = hasDeviceExtension(physical_, VK_EXT_SUBGROUP_SIZE_CONTROL_EXTENSION_NAME);
  if (hasSizeControl) driver.pNext = &sizeControl;
  VkPhysicalDeviceMaintenance3Properties maintenance3{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_MAINTENANCE_3_PROPERTIES};
  maintenance3.pNext = &subgroup;
  VkPhysicalDeviceProperties2 props2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2};
  props2.pNext = &maintenance3;
  vkGetPhysicalDeviceProperties2(physical_, &props2);
  const auto& p = props2.properties;
  const auto& l = p.limits;
  caps_.name = p.deviceName;
  caps_.type = p.deviceType;
  caps_.apiVersion = p.apiVersion;
  caps_.driverId = driver.driverID;
  caps_.driverInfo = driver.driverInfo;
  caps_.driverVersion = p.driverVersion;
  // A driver that leaves its info empty (SwiftShader) is named by its name and version (in
  // Vulkan's own encoding, which SwiftShader uses: 5.0.0).
  if (caps_.driverInfo.empty() && driver.driverName[0])
    caps_.driverInfo = std::string(driver.driverName) + " " + std::to_string(VK_API_VERSION_MAJOR(p.driverVersion)) +
                       "." + std::to_string(VK_API_VERSION_MINOR(p.driverVersion)) + "." +
                       std::to_string(VK_API_VERSION_PATCH(p.driverVersion));
  if (caps_.driverInfo.rfind("Mesa ", 0) == 0) caps_.mesaMajor = static_cast<uint32_t>(std::atoi(caps_.driverInfo.c_str() + 5));
  caps_.vendorId = p.vendorID;
  caps_.deviceId = p.deviceID;
  caps_.subgroupSize = subgroup.subgroupSize;
  caps_.minSubgroupSize = hasSizeControl ? sizeControl.minSubgroupSize : subgroup.subgroupSize;
  caps_.maxSubgroupSize = hasSizeControl ? sizeControl.maxSubgroupSize : subgroup.subgroupSize;
  caps_.requiredSubgroupSize = hasSizeControl && (sizeControl.requiredSubgroupSizeStages & VK_SHADER_STAGE_COMPUTE_BIT);
  caps_.subgroupArithmetic = (subgroup.supportedStages & VK_SHADER_STAGE_COMPUTE_BIT) &&
                             (subgroup.supportedOperations & VK_SUBGROUP_FEATURE_ARITHMETIC_BIT);
  caps_.subgroupShuffle = (subgroup.supportedStages & VK_SHADER_STAGE_COMPUTE_BIT) &&
                          (subgroup.supportedOperations & VK_SUBGROUP_FEATURE_SHUFFLE_BIT);
  caps_.maxStorageBufferRange = l.maxStorageBufferRange;
  caps_.maxTexelBufferElements = l.maxTexelBufferElements;
  caps_.minStorageBufferOffsetAlignment = l.minStorageBufferOffsetAlignment;
  caps_.minTexelBufferOffsetAlignment = l.minTexelBufferOffsetAlignment;
  caps_.maxMemoryAllocationSize = maintenance3.maxMemoryAllocationSize;
  caps_.maxPushConstantsSize = l.maxPushConstantsSize;
  for (int i = 0; i < 3; ++i) caps_.maxWorkGroupCount[i] = l.maxComputeWorkGroupCount[i];
  caps_.maxWorkGroupInvocations = l.maxComputeWorkGroupInvocations;
  caps_.maxSharedMemory = l.maxComputeSharedMemorySize;
  caps_.maxPerStageStorageBuffers = l.maxPerStageDescriptorStorageBuffers;
  caps_.maxPerStageSampledImages = l.maxPerStageDescriptorSampledImages;
  caps_.timestampPeriodNs = l.timestampPeriod;

  uint32_t familyCount = 0;
  vkGetPhysicalDeviceQueueFamilyProperties(physical_, &familyCount, nullptr);
  std::vector<VkQueueFamilyProperties> families(familyCount);
  vkGetPhysicalDeviceQueueFamilyProperties(physical_, &familyCount, families.data());
  bool found = false;
  for (uint32_t i = 0; i < familyCount; ++i) {
    if (families[i].queueFlags & VK_QUEUE_COMPUTE_BIT) {
      queueFamily_ = i;
      found = true;
      caps_.timestamps = families[i].timestampValidBits > 0 && l.timestampComputeAndGraphics;
      break;
    }
  }
  if (!found) throw Error(caps_.name + " has no compute queue");

  VkPhysicalDeviceVulkan11Features f11{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_1_FEATURES};
  VkPhysicalDeviceVulkan12Features f12{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES};
  f11.pNext = &f12;
  VkPhysicalDeviceFeatures2 features{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2};
  features.pNext = &f11;
  vkGetPhysicalDeviceFeatures2(physical_, &features);
  caps_.shaderFloat16 = f12.shaderFloat16;
  caps_.storageBuffer16BitAccess = f11.storageBuffer16BitAccess;
  if (hasSizeControl) {
    VkPhysicalDeviceSubgroupSizeControlFeaturesEXT size{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_SIZE_CONTROL_FEATURES_EXT};
    VkPhysicalDeviceFeatures2 f2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2};
    f2.pNext = &size;
    vkGetPhysicalDeviceFeatures2(physical_, &f2);
    caps_.fullSubgroups = size.subgroupSizeControl && size.computeFullSubgroups;
    caps_.requiredSubgroupSize = caps_.requiredSubgroupSize && size.subgroupSizeControl;
  }
  // The cooperative-matrix kernel's SPIR-V uses the Vulkan memory model (what glslang emits
  // for cooperative-matrix loads and stores; with it on, the device scope of other kernels'
  // atomics needs vulkanMemoryModelDeviceScope), and its subgroups must be full (SPIR-V
  // before 1.6): all of them are needed.
  if (f12.vulkanMemoryModel && f12.vulkanMemoryModelDeviceScope && caps_.fullSubgroups &&
      hasDeviceExtension(physical_, VK_KHR_COOPERATIVE_MATRIX_EXTENSION_NAME)) {
    VkPhysicalDeviceCooperativeMatrixFeaturesKHR coop{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_COOPERATIVE_MATRIX_FEATURES_KHR};
    VkPhysicalDeviceFeatures2 f2{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2};
    f2.pNext = &coop;
    vkGetPhysicalDeviceFeatures2(physical_, &f2);
    if (coop.cooperativeMatrix) {
      caps_.coopMatSizes = coopMatSizes(instance_, physical_);
      caps_.cooperativeMatrix = !caps_.coopMatSizes.empty();
    }
  }
  caps_.fp16TexelBuffers = texelFormatSupported(physical_, VK_FORMAT_R16G16B16A16_SFLOAT) &&
                           texelFormatSupported(physical_, VK_FORMAT_R16_SFLOAT);
  if (!texelFormatSupported(physical_, VK_FORMAT_R32G32B32A32_SFLOAT) ||
      !texelFormatSupported(physical_, VK_FORMAT_R32_SFLOAT))
    throw Error(caps_.name + " cannot read fp32 uniform texel buffers, which the engine's kernels need");

  vkGetPhysicalDeviceMemoryProperties(physical_, &memory_);
  const VkMemoryPropertyFlags both = VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT | VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT |
                                     VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
  for (uint32_t i = 0; i < memory_.memoryTypeCount; ++i) {
    const auto& type = memory_.memoryTypes[i];
    // A small host-visible device heap (the 256 MiB BAR window of a discrete GPU) cannot
    // hold a model; only a heap of at least 1 GiB counts as "map it directly".
    if ((type.propertyFlags & both) == both && memory_.memoryHeaps[type.heapIndex].size >= (1ull << 30))
      caps_.hostVisibleDeviceLocal = true;
  }
  bindingRangeLimit_ = caps_.maxStorageBufferRange;
}

void Device::createLogicalDevice() {
  float priority = 1.0f;
  VkDeviceQueueCreateInfo queueInfo{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
  queueInfo.queueFamilyIndex = queueFamily_;
  queueInfo.queueCount = 1;
  queueInfo.pQueuePriorities = &priority;

  // Enable only what the kernels use, and only where the device has it; fp16 kernels check
  // caps().supportsFp16Storage() and refuse with a clear message otherwise.
  VkPhysicalDeviceVulkan11Features f11{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_1_FEATURES};
  VkPhysicalDeviceVulkan12Features f12{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_FEATURES};
  f11.pNext = &f12;
  f11.storageBuffer16BitAccess = caps_.storageBuffer16BitAccess;
  f12.shaderFloat16 = caps_.shaderFloat16;
  VkPhysicalDeviceFeatures2 features{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2};
  features.pNext = &f11;
  // Full subgroups (kernels that divide a workgroup among its subgroups) and cooperative
  // matrices (the GEMM of fp16 weights on GPUs that have them).
  std::vector<const char*> extensions;
  void** tail = &f12.pNext;
  VkPhysicalDeviceSubgroupSizeControlFeaturesEXT size{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_SIZE_CONTROL_FEATURES_EXT};
  if (caps_.fullSubgroups) {
    size.subgroupSizeControl = VK_TRUE;
    size.computeFullSubgroups = VK_TRUE;
    *tail = &size;
    tail = &size.pNext;
    extensions.push_back(VK_EXT_SUBGROUP_SIZE_CONTROL_EXTENSION_NAME);
  }
  VkPhysicalDeviceCooperativeMatrixFeaturesKHR coop{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_COOPERATIVE_MATRIX_FEATURES_KHR};
  if (caps_.cooperativeMatrix) {
    coop.cooperativeMatrix = VK_TRUE;
    f12.vulkanMemoryModel = VK_TRUE;
    f12.vulkanMemoryModelDeviceScope = VK_TRUE;  // the other kernels' device-scope atomics
    *tail = &coop;
    extensions.push_back(VK_KHR_COOPERATIVE_MATRIX_EXTENSION_NAME);
  }

  VkDeviceCreateInfo info{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO};
  info.pNext = &features;
  info.enabledExtensionCount = static_cast<uint32_t>(extensions.size());
  info.ppEnabledExtensionNames = extensions.data();
  info.queueCreateInfoCount = 1;
  info.pQueueCreateInfos = &queueInfo;
  SPAR_VK(vkCreateDevice(physical_, &info, nullptr, &device_));
  vkGetDeviceQueue(device_, queueFamily_, 0, &queue_);
}

size_t Device::validationMessageCount() const {
  std::lock_guard<std::mutex> lock(messagesMutex_);
  return messages_.size();
}

std::vector<std::string> Device::validationMessages() const {
  std::lock_guard<std::mutex> lock(messagesMutex_);
  return messages_;
}

void Device::recordValidationMessage(const std::string& message) {
  std::lock_guard<std::mutex> lock(messagesMutex_);
  messages_.push_back(message);
}

}  // namespace spar
