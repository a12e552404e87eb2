// Errors the engine reports: one exception type whose message is a single readable line.
#pragma once
#include <vulkan/vulkan.h>

#include <stdexcept>
#include <string>

namespace spar {

struct Error : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Name and meaning of a VkResult, e.g. "VK_ERROR_OUT_OF_DEVICE_MEMORY (device memory exhausted)".
std::string describeVkResult(VkResult result);

// Throws Error("<what> failed: <describeVkResult>") unless result is VK_SUCCESS.
void vkCheck(VkResult result, const char* what);

}  // namespace spar

#define SPAR_VK(call) ::spar::vkCheck((call), #call)
