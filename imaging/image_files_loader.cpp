// Finds and loads spar_image_files.so (imaging/image_files.h) the first time an image file is
// touched. Where it looks, in order: $SPAR_IMAGE_FILES_MODULE; beside the binary or library that
// holds this code; spar/ and LIBDIR/spar/ in its folder and the two above it (an installed
// prefix's lib/spar/ from bin/spar, lib/libspar.so or the Python module); the build tree's
// module; the configured install's.
#include <dlfcn.h>

#include <cstdlib>
#include <filesystem>
#include <mutex>
#include <vector>

#include "spar/error.h"
#include "imaging/image_files.h"

namespace spar {
namespace {

namespace fs = std::filesystem;

constexpr const char* kModuleName = "spar_image_files.so";

std::vector<fs::path> candidates() {
  std::vector<fs::path> paths;
  if (const char* set = std::getenv("SPAR_IMAGE_FILES_MODULE"); set && *set) return {fs::path(set)};
  Dl_info info{};
  if (dladdr(reinterpret_cast<void*>(&imageFiles), &info) && info.dli_fname && *info.dli_fname) {
    std::error_code ec;
    const fs::path self = fs::canonical(info.dli_fname, ec);
    if (!ec) {
      // The binary's or library's folder and up to two above it (bin/, lib/, and the Python
      // module's lib/python3/dist-packages/ of an installed prefix), each as LIBDIR's folder
      // (its spar/) and as the prefix (its LIBDIR/spar/).
      fs::path dir = self.parent_path();
      paths.push_back(dir / kModuleName);
      for (int up = 0; up < 3 && !dir.empty(); ++up, dir = dir.parent_path()) {
        paths.push_back(dir / "spar" / kModuleName);
        paths.push_back(dir / SPAR_INSTALL_LIBDIR / "spar" / kModuleName);
      }
    }
  }
  paths.push_back(SPAR_IMAGE_FILES_BUILD_MODULE);
  paths.push_back(fs::path(SPAR_INSTALL_FULL_LIBDIR) / "spar" / kModuleName);
  return paths;
}

const ImageFiles* load(std::string* why) {
  std::string tried;
  for (const fs::path& path : candidates()) {
    std::error_code ec;
    if (!fs::is_regular_file(path, ec)) {
      tried += (tried.empty() ? "" : ", ") + path.string();
      continue;
    }
    // Never unloaded: OpenImageIO keeps thread pools and plugin state until exit.
    void* handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (!handle) {
      *why = path.string() + ": " + dlerror();
      return nullptr;
    }
    auto entry = reinterpret_cast<const ImageFiles* (*)()>(dlsym(handle, "spar_image_files_v1"));
    if (!entry) {
      *why = path.string() + ": not this version's module (no spar_image_files_v1)";
      return nullptr;
    }
    return entry();
  }
  *why = std::string(kModuleName) + " not found (looked at " + tried + ")";
  return nullptr;
}

}  // namespace

const ImageFiles& imageFiles() {
  static std::once_flag once;
  static const ImageFiles* files = nullptr;
  static std::string why;
  std::call_once(once, [] { files = load(&why); });
  if (!files) throw Error("cannot read or write image files: " + why);
  return *files;
}

}  // namespace spar
