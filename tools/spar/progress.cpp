#include "tools/spar/progress.h"

#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include "spar/engine_options.h"

namespace spar::cli {

Progress::Progress() : tty_(::isatty(STDERR_FILENO) == 1) {}

void Progress::step(const std::string& text) {
  if (tty_) {
    std::fprintf(stderr, "\r\033[Kspar: %s", text.c_str());
    open_ = true;
  } else {
    std::fprintf(stderr, "spar: %s\n", text.c_str());
  }
  std::fflush(stderr);
}

void Progress::finish() {
  if (open_) std::fputc('\n', stderr);
  open_ = false;
}

std::string pipelineCachePath() { return EngineOptions::defaultPipelineCacheFile(); }

}  // namespace spar::cli
