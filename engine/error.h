// Errors the engine reports: one exception type whose message is a single readable line.
#pragma once
#include <vulkan/vulkan.h>

#include <string>

#include "spar/error.h"  // spar::Error, the public exception type

namespace spar {

// Name and meaning of a VkResult, e.g. "VK_ERROR_OUT_OF_DEVICE_MEMORY (device memory exhausted)".
std::string describeVkResult(VkResult result);

// Throws Error("<what> failed: <describeVkResult>") unless result is VK_SUCCESS.
void vkCheck(VkResult result, const char* what);

}  // namespace spar

#define SPAR_VK(call) ::spar::vkCheck((call), #call)
