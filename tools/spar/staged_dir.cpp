#include "tools/spar/staged_dir.h"

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fcntl.h>
#include <unistd.h>
#include <filesystem>
#include <system_error>
#include <vector>

#include "spar/error.h"
#include "formats/cameras.h"

namespace spar::cli {

namespace fs = std::filesystem;

void checkWritable(const std::string& dir, const std::string& forWhat) {
  // Only trying tells (permissions, read-only mounts, /proc): make and remove an empty
  // directory where the output's temporary will go.
  std::string probe = (fs::path(dir) / ".spar-probe-XXXXXX").string();
  std::vector<char> buf(probe.begin(), probe.end());
  buf.push_back('\0');
  if (!::mkdtemp(buf.data())) throw Error("cannot write in " + dir + " (for " + forWhat + "): " + std::strerror(errno));
  ::rmdir(buf.data());
}

std::string checkOutDir(const std::string& path) {
  const std::string abs = absolutePath(path);
  std::error_code ec;
  if (fs::exists(fs::symlink_status(abs, ec))) throw Error("output directory already exists: " + abs);
  const fs::path parent = fs::path(abs).parent_path();
  if (!fs::is_directory(parent, ec)) {
    // Say which part of the path is wrong: a file where a directory should be, or nothing.
    for (fs::path p = parent; !p.empty() && p != p.parent_path(); p = p.parent_path())
      if (fs::exists(p, ec)) {
        if (!fs::is_directory(p, ec)) throw Error("cannot create " + abs + ": " + p.string() + " is a file, not a directory");
        break;
      }
    throw Error("parent directory does not exist: " + parent.string());
  }
  checkWritable(parent.string(), abs);
  return abs;
}

StagedDir::StagedDir(const std::string& finalPath) : final_(finalPath) {
  std::string templ = final_ + ".tmp-XXXXXX";
  std::vector<char> buf(templ.begin(), templ.end());
  buf.push_back('\0');
  if (!::mkdtemp(buf.data()))
    throw Error("cannot create a temporary directory next to " + final_ + ": " + std::strerror(errno));
  tmp_ = buf.data();
}

StagedDir::~StagedDir() {
  if (committed_) return;
  std::error_code ec;
  fs::remove_all(tmp_, ec);
}

void StagedDir::commit() {
  int rc = ::renameat2(AT_FDCWD, tmp_.c_str(), AT_FDCWD, final_.c_str(), RENAME_NOREPLACE);
  if (rc != 0 && (errno == EINVAL || errno == ENOSYS)) {
    // No RENAME_NOREPLACE here: check, then rename (a race remains, as in the reference).
    std::error_code ec;
    if (fs::exists(fs::symlink_status(final_, ec))) {
      errno = EEXIST;
    } else {
      rc = std::rename(tmp_.c_str(), final_.c_str());
    }
  }
  if (rc != 0) {
    if (errno == EEXIST || errno == ENOTEMPTY) throw Error("output directory appeared while writing: " + final_);
    throw Error("cannot rename " + tmp_ + " to " + final_ + ": " + std::strerror(errno));
  }
  committed_ = true;
}

}  // namespace spar::cli
