// Vulkan drivers installed where the Vulkan loader does not look by default. SwiftShader, the
// CPU driver Chromium and the Android emulator fall back to, comes inside browser packages
// (Debian's chromium: /usr/lib/chromium/vk_swiftshader_icd.json); a user who asks for it by
// name (`--device swiftshader`) gets it without setting loader variables. Such a driver joins an
// instance only when asked for: the default choice and device indices stay those of the drivers
// the loader finds itself.
#pragma once
#include <string>
#include <vector>

namespace spar {

// The installed manifests of the extra drivers whose device `select` names: a case-insensitive
// part of the device's name ("swiftshader", "subzero"), or a name containing the driver's
// ("SwiftShader Device (Subzero)"). "*" names every one; an index names none. Empty when the
// user chose the drivers (VK_ICD_FILENAMES or VK_DRIVER_FILES set): theirs are the only ones.
std::vector<std::string> extraDriverManifests(const std::string& select);

// When `select` names an extra driver that is not installed: one sentence saying where it was
// looked for and which package installs it; else "".
std::string missingExtraDriver(const std::string& select);

// Adds `manifests` to VK_ADD_DRIVER_FILES for the Vulkan instances created in its scope (the
// loader reads the variable at vkCreateInstance); the variable is restored when it ends.
class ScopedExtraDrivers {
 public:
  explicit ScopedExtraDrivers(const std::vector<std::string>& manifests);
  ~ScopedExtraDrivers();
  ScopedExtraDrivers(const ScopedExtraDrivers&) = delete;
  ScopedExtraDrivers& operator=(const ScopedExtraDrivers&) = delete;

 private:
  bool changed_ = false, hadValue_ = false;
  std::string oldValue_;
};

}  // namespace spar
