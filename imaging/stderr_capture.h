// Holds what a library prints on stderr while in scope (libpng's "libpng error: ..." through
// OpenImageIO, for one), so that it can be folded into our one-line error instead of reaching
// the terminal as extra lines. The process's stderr file descriptor is swapped for a temporary
// file: use it on one thread, around one library call at a time.
#pragma once
#include <string>

namespace spar {

class StderrCapture {
 public:
  StderrCapture();
  ~StderrCapture();  // restores stderr; what was captured and not taken is dropped
  StderrCapture(const StderrCapture&) = delete;
  StderrCapture& operator=(const StderrCapture&) = delete;

  // Restores stderr and returns what was printed meanwhile, as one line ("" if nothing).
  std::string take();

 private:
  int saved_ = -1;
  int file_ = -1;
};

}  // namespace spar
