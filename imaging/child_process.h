// Helper programs the engine runs (ffmpeg, ffprobe: Debian's ffmpeg package): where they are,
// and one run with its output collected. posix_spawn, no shell: arguments are passed as they are.
#pragma once
#include <cstddef>
#include <string>
#include <vector>

namespace spar {

// The first executable `name` on PATH; "" when there is none.
std::string findOnPath(const std::string& name);
// ffmpeg: SPAR_FFMPEG if set (a path; "" or a non-executable means none), else the first on PATH.
std::string findFfmpeg();
// ffprobe: the one beside findFfmpeg()'s ffmpeg, else the first on PATH; "" when there is none.
std::string findFfprobe();

struct ProcessOutput {
  int exitCode = -1;   // -1: killed (a signal, the time limit, or more output than allowed)
  std::string out;     // stdout, at most the limit given
  std::string err;     // stderr (the last 64 KiB)
  bool timedOut = false, tooLong = false;
};

// Runs argv[0] with argv, stdin from /dev/null, until it exits or `timeoutMs` passes (then it
// is killed). Stdout beyond `maxOut` bytes kills it too (tooLong). Throws spar::Error only when
// the program cannot be started.
ProcessOutput runProcess(const std::vector<std::string>& argv, size_t maxOut, int timeoutMs);

// The last non-empty lines of a program's stderr joined by " | " (at most `lines`): the part of
// its complaint that goes into a one-line error.
std::string lastLines(const std::string& text, int lines = 2);

}  // namespace spar
