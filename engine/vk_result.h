// Vulkan's result codes as spar::Error (include/spar/error.h): the one place outside the
// engine's own Vulkan calls that knows VkResult. Code that only throws includes spar/error.h.
#pragma once
#include <vulkan/vulkan.h>

#include <string>

#include "spar/error.h"

namespace spar {

// Name and meaning of a VkResult, e.g. "VK_ERROR_OUT_OF_DEVICE_MEMORY (device memory exhausted)".
std::string describeVkResult(VkResult result);

// Throws Error("<what> failed: <describeVkResult>") unless result is VK_SUCCESS.
void vkCheck(VkResult result, const char* what);

}  // namespace spar

#define SPAR_VK(call) ::spar::vkCheck((call), #call)
