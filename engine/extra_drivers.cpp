#include "engine/extra_drivers.h"

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <filesystem>

namespace spar {
namespace {

struct ExtraDriver {
  const char* deviceName;              // as the driver reports it
  const char* keyword;                 // a name containing it asks for this driver
  const char* package;                 // what installs it on Debian
  std::vector<const char*> manifests;  // where packages install it, first found wins
};

// SwiftShader: Debian's and Ubuntu's chromium, Fedora's chromium, Google Chrome.
const std::vector<ExtraDriver>& extraDrivers() {
  static const std::vector<ExtraDriver> drivers = {
      {"SwiftShader Device (Subzero)", "swiftshader", "apt-get install chromium",
       {"/usr/lib/chromium/vk_swiftshader_icd.json", "/usr/lib/chromium-browser/vk_swiftshader_icd.json",
        "/usr/lib64/chromium-browser/vk_swiftshader_icd.json", "/opt/google/chrome/vk_swiftshader_icd.json"}},
  };
  return drivers;
}

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

bool set(const char* name) {
  const char* v = std::getenv(name);
  return v && *v;
}

// The extra drivers `select` names (see extraDriverManifests).
std::vector<const ExtraDriver*> named(const std::string& select) {
  std::vector<const ExtraDriver*> out;
  if (select.empty() || std::all_of(select.begin(), select.end(), [](unsigned char c) { return std::isdigit(c); }))
    return out;
  const std::string want = lower(select);
  for (const ExtraDriver& d : extraDrivers())
    if (want == "*" || lower(d.deviceName).find(want) != std::string::npos || want.find(d.keyword) != std::string::npos)
      out.push_back(&d);
  return out;
}

std::string installedManifest(const ExtraDriver& d) {
  for (const char* m : d.manifests) {
    std::error_code ec;
    if (std::filesystem::is_regular_file(m, ec)) return m;
  }
  return "";
}

}  // namespace

std::vector<std::string> extraDriverManifests(const std::string& select) {
  std::vector<std::string> out;
  if (set("VK_ICD_FILENAMES") || set("VK_DRIVER_FILES")) return out;
  for (const ExtraDriver* d : named(select))
    if (const std::string m = installedManifest(*d); !m.empty()) out.push_back(m);
  return out;
}

std::string missingExtraDriver(const std::string& select) {
  for (const ExtraDriver* d : named(select)) {
    if (!installedManifest(*d).empty()) continue;
    std::string places;
    for (const char* m : d->manifests) places += (places.empty() ? "" : ", ") + std::string(m);
    return std::string(d->deviceName) + " is not installed (looked for " + places + "; " + d->package + ")";
  }
  return "";
}

ScopedExtraDrivers::ScopedExtraDrivers(const std::vector<std::string>& manifests) {
  if (manifests.empty()) return;
  const char* old = std::getenv("VK_ADD_DRIVER_FILES");
  hadValue_ = old != nullptr;
  if (old) oldValue_ = old;
  std::string value = oldValue_;
  for (const std::string& m : manifests) {
    if ((":" + value + ":").find(":" + m + ":") != std::string::npos) continue;  // the user added it already
    value += (value.empty() ? "" : ":") + m;
  }
  setenv("VK_ADD_DRIVER_FILES", value.c_str(), 1);
  changed_ = true;
}

ScopedExtraDrivers::~ScopedExtraDrivers() {
  if (!changed_) return;
  if (hadValue_)
    setenv("VK_ADD_DRIVER_FILES", oldValue_.c_str(), 1);
  else
    unsetenv("VK_ADD_DRIVER_FILES");
}

}  // namespace spar
