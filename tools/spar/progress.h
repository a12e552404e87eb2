// Shared by the `spar` subcommands: progress lines on stderr and the driver's pipeline cache.
#pragma once
#include <string>

namespace spar::cli {

// Progress on stderr: one line per phase; on a terminal the line is rewritten in place so the
// run shows as a single updating line.
class Progress {
 public:
  Progress();
  ~Progress() { finish(); }
  Progress(const Progress&) = delete;
  Progress& operator=(const Progress&) = delete;
  void step(const std::string& text);
  // Ends the updating line (before an error message or at the end).
  void finish();

 private:
  bool tty_ = false, open_ = false;
};

// The driver's pipeline cache between runs ($XDG_CACHE_HOME/spar or ~/.cache/spar; "" when
// neither is set or the directory cannot be made): drivers that keep compiled code in it start
// faster on the second run. SPAR_PIPELINE_CACHE=0 turns it off.
std::string pipelineCachePath();

}  // namespace spar::cli
