#include "imaging/stderr_capture.h"

#include <unistd.h>

#include <cstdio>
#include <cstdlib>

namespace spar {

StderrCapture::StderrCapture() {
  std::fflush(stderr);
  char name[] = "/tmp/spar-stderr-XXXXXX";
  file_ = ::mkstemp(name);
  if (file_ < 0) return;  // nothing captured: the library's lines then still reach stderr
  ::unlink(name);
  saved_ = ::dup(STDERR_FILENO);
  if (saved_ < 0 || ::dup2(file_, STDERR_FILENO) < 0) {
    if (saved_ >= 0) ::close(saved_);
    saved_ = -1;
  }
}

std::string StderrCapture::take() {
  std::string text;
  if (saved_ >= 0) {
    std::fflush(stderr);
    ::dup2(saved_, STDERR_FILENO);
    ::close(saved_);
    saved_ = -1;
    char buf[512];
    ::lseek(file_, 0, SEEK_SET);
    for (ssize_t n; (n = ::read(file_, buf, sizeof(buf))) > 0 && text.size() < 4096;) text.append(buf, size_t(n));
  }
  for (char& c : text)
    if (c == '\n' || c == '\r') c = ' ';
  while (!text.empty() && text.back() == ' ') text.pop_back();
  return text;
}

StderrCapture::~StderrCapture() {
  take();
  if (file_ >= 0) ::close(file_);
}

}  // namespace spar
