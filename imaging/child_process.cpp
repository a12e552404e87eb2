#include "imaging/child_process.h"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <sstream>

#include "spar/error.h"

extern char** environ;

namespace spar {
namespace {

bool isExecutable(const std::string& p) { return !p.empty() && ::access(p.c_str(), X_OK) == 0 && !std::filesystem::is_directory(p); }

}  // namespace

std::string findOnPath(const std::string& name) {
  const char* path = std::getenv("PATH");
  std::stringstream dirs(path ? path : "/usr/bin:/bin");
  std::string dir;
  while (std::getline(dirs, dir, ':')) {
    const std::string p = (std::filesystem::path(dir.empty() ? "." : dir) / name).string();
    if (isExecutable(p)) return p;
  }
  return "";
}

std::string findFfmpeg() {
  if (const char* e = std::getenv("SPAR_FFMPEG")) return isExecutable(e) ? std::string(e) : std::string();
  return findOnPath("ffmpeg");
}

std::string findFfprobe() {
  const std::string ffmpeg = findFfmpeg();
  if (!ffmpeg.empty()) {
    const std::string beside = (std::filesystem::path(ffmpeg).parent_path() / "ffprobe").string();
    if (isExecutable(beside)) return beside;
  }
  if (std::getenv("SPAR_FFMPEG")) return "";  // ffmpeg named elsewhere (or none): no other ffprobe
  return findOnPath("ffprobe");
}

ProcessOutput runProcess(const std::vector<std::string>& args, size_t maxOut, int timeoutMs) {
  int outPipe[2], errPipe[2];
  if (::pipe2(outPipe, O_CLOEXEC) != 0) throw Error("cannot run " + args.at(0) + ": pipe: " + std::strerror(errno));
  if (::pipe2(errPipe, O_CLOEXEC) != 0) {
    ::close(outPipe[0]);
    ::close(outPipe[1]);
    throw Error("cannot run " + args.at(0) + ": pipe: " + std::strerror(errno));
  }
  std::vector<std::string> copy = args;
  std::vector<char*> argv;
  for (auto& s : copy) argv.push_back(s.data());
  argv.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_adddup2(&actions, outPipe[1], 1);
  posix_spawn_file_actions_adddup2(&actions, errPipe[1], 2);
  pid_t child = -1;
  const int rc = ::posix_spawn(&child, argv[0], &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  ::close(outPipe[1]);
  ::close(errPipe[1]);
  if (rc != 0) {
    ::close(outPipe[0]);
    ::close(errPipe[0]);
    throw Error("cannot run " + args[0] + ": " + std::strerror(rc));
  }

  ProcessOutput r;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeoutMs);
  pollfd fds[2] = {{outPipe[0], POLLIN, 0}, {errPipe[0], POLLIN, 0}};
  int open = 2;
  char buf[65536];
  bool kill = false;
  while (open > 0) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - std::chrono::steady_clock::now()).count();
    if (left <= 0) {
      r.timedOut = kill = true;
      break;
    }
    const int n = ::poll(fds, 2, int(std::min<long long>(left, 1000)));
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) break;
    for (int i = 0; i < 2; ++i) {
      if (fds[i].fd < 0 || !(fds[i].revents & (POLLIN | POLLHUP | POLLERR))) continue;
      const ssize_t got = ::read(fds[i].fd, buf, sizeof buf);
      if (got < 0 && errno == EINTR) continue;
      if (got <= 0) {
        ::close(fds[i].fd);
        fds[i].fd = -1;
        --open;
        continue;
      }
      std::string& sink = i == 0 ? r.out : r.err;
      sink.append(buf, size_t(got));
      if (i == 1 && r.err.size() > 65536) r.err.erase(0, r.err.size() - 65536);
      if (i == 0 && r.out.size() > maxOut) {
        r.out.resize(maxOut);
        r.tooLong = kill = true;
      }
    }
    if (kill) break;
  }
  for (const pollfd& f : fds)
    if (f.fd >= 0) ::close(f.fd);
  if (kill) ::kill(child, SIGKILL);
  int status = 0;
  while (::waitpid(child, &status, 0) < 0 && errno == EINTR) {
  }
  r.exitCode = (!kill && WIFEXITED(status)) ? WEXITSTATUS(status) : -1;
  return r;
}

std::string lastLines(const std::string& text, int lines) {
  std::vector<std::string> all;
  std::stringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    const size_t b = line.find_first_not_of(" \t\r"), e = line.find_last_not_of(" \t\r");
    if (b != std::string::npos) all.push_back(line.substr(b, e - b + 1));
  }
  std::string out;
  for (size_t i = all.size() > size_t(lines) ? all.size() - size_t(lines) : 0; i < all.size(); ++i)
    out += (out.empty() ? "" : " | ") + all[i];
  return out;
}

}  // namespace spar
