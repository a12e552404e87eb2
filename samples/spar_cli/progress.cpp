#include "samples/spar_cli/progress.h"

#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>

namespace spar::cli {

namespace fs = std::filesystem;

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

std::string pipelineCachePath() {
  const char* off = std::getenv("SPAR_PIPELINE_CACHE");
  if (off && std::string(off) == "0") return "";
  const char* xdg = std::getenv("XDG_CACHE_HOME");
  const char* home = std::getenv("HOME");
  fs::path dir = xdg && *xdg ? fs::path(xdg) / "spar" : home && *home ? fs::path(home) / ".cache" / "spar" : fs::path();
  if (dir.empty()) return "";
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return "";
  return (dir / "pipelines.bin").string();
}

}  // namespace spar::cli
