// The output directory appears whole or not at all: files go into a fresh DIR.tmp-XXXXXX next
// to DIR, which is renamed to DIR when everything is written (commit) and removed otherwise
// (destructor), as the reference's staged_dir does.
#pragma once
#include <string>

namespace spar::cli {

// Absolute, normalized output path; throws spar::Error if it exists or its parent does not.
// Throws spar::Error unless a directory can be made in `dir` (tried, then removed): before any
// work, so an unwritable output location costs nothing.
void checkWritable(const std::string& dir, const std::string& forWhat);

std::string checkOutDir(const std::string& path);

class StagedDir {
 public:
  explicit StagedDir(const std::string& finalPath);  // creates the temporary directory
  ~StagedDir();                                       // removes it unless committed
  StagedDir(const StagedDir&) = delete;
  StagedDir& operator=(const StagedDir&) = delete;

  const std::string& path() const { return tmp_; }
  // Renames the temporary directory to the final path; refuses to replace anything that
  // appeared there meanwhile (renameat2 RENAME_NOREPLACE where the file system has it).
  void commit();

 private:
  std::string final_, tmp_;
  bool committed_ = false;
};

}  // namespace spar::cli
