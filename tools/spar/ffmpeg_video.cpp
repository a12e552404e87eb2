#include "tools/spar/ffmpeg_video.h"

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <vector>

#include "spar/error.h"
#include "imaging/child_process.h"

extern char** environ;

namespace spar::cli {

namespace {

// The last lines of ffmpeg's log folded into one line (it prints one problem per line).
std::string logTail(const std::string& log) {
  std::ifstream f(log);
  std::stringstream text;
  text << f.rdbuf();
  return lastLines(text.str(), 3);
}

}  // namespace

FfmpegVideo::FfmpegVideo(const std::string& ffmpeg, const std::string& path, int fps)
    : ffmpeg_(ffmpeg), path_(path), log_(path + ".log"), fps_(fps) {}

FfmpegVideo::~FfmpegVideo() {
  if (stdin_ >= 0) ::close(stdin_);
  if (child_ > 0) {
    ::kill(child_, SIGKILL);
    int status = 0;
    while (::waitpid(child_, &status, 0) < 0 && errno == EINTR) {
    }
  }
  std::error_code ec;
  std::filesystem::remove(log_, ec);
}

std::string FfmpegVideo::failure(const std::string& what) {
  const std::string tail = logTail(log_);
  return "cannot write " + path_ + ": " + what + (tail.empty() ? "" : " (ffmpeg: " + tail + ")");
}

void FfmpegVideo::start(int width, int height) {
  width_ = width;
  height_ = height;
  // A socket rather than a pipe so that writes after ffmpeg died fail with EPIPE through
  // MSG_NOSIGNAL instead of raising SIGPIPE in the whole process.
  int fds[2];
  if (::socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, fds) != 0)
    throw Error("cannot write " + path_ + ": socketpair: " + std::strerror(errno));
  const std::string size = std::to_string(width) + "x" + std::to_string(height);
  const std::string rate = std::to_string(fps_);
  std::vector<std::string> args = {ffmpeg_, "-hide_banner", "-nostats", "-loglevel", "error", "-y",
                                   "-f", "rawvideo", "-pix_fmt", "rgb24", "-video_size", size, "-framerate", rate,
                                   "-i", "pipe:0",
                                   // yuv420p needs even sizes: pad odd ones with one black row / column; CRF 18: visually
                                   // lossless for x264, so the video shows what was rendered
                                   "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-c:v", "libx264", "-crf", "18", "-pix_fmt", "yuv420p",
                                   "-movflags", "+faststart", "-f", "mp4", path_};
  std::vector<char*> argv;
  for (auto& s : args) argv.push_back(s.data());
  argv.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_adddup2(&actions, fds[0], 0);  // dup2 clears CLOEXEC on fd 0
  posix_spawn_file_actions_addopen(&actions, 1, log_.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&actions, 1, 2);
  const int rc = ::posix_spawn(&child_, ffmpeg_.c_str(), &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  ::close(fds[0]);
  if (rc != 0) {
    child_ = -1;
    ::close(fds[1]);
    throw Error("cannot write " + path_ + ": cannot run " + ffmpeg_ + ": " + std::strerror(rc));
  }
  stdin_ = fds[1];
}

void FfmpegVideo::add(const RgbImage& frame) {
  if (child_ < 0) start(frame.width, frame.height);
  if (frame.width != width_ || frame.height != height_) throw Error("animation frames differ in size: " + path_);
  const uint8_t* p = frame.pixels.data();
  size_t left = frame.pixels.size();
  while (left > 0) {
    const ssize_t n = ::send(stdin_, p, left, MSG_NOSIGNAL);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) throw Error(failure("ffmpeg stopped reading frames"));
    p += n;
    left -= size_t(n);
  }
}

void FfmpegVideo::finish() {
  if (child_ < 0) throw Error("no frames to animate in " + path_);
  ::close(stdin_);
  stdin_ = -1;
  int status = 0;
  pid_t r;
  while ((r = ::waitpid(child_, &status, 0)) < 0 && errno == EINTR) {
  }
  child_ = -1;
  if (r < 0) throw Error(failure(std::string("waitpid: ") + std::strerror(errno)));
  if (WIFSIGNALED(status)) throw Error(failure("ffmpeg was killed by signal " + std::to_string(WTERMSIG(status))));
  if (WEXITSTATUS(status) != 0) throw Error(failure("ffmpeg exited with status " + std::to_string(WEXITSTATUS(status))));
  std::error_code ec;
  if (std::filesystem::file_size(path_, ec) == 0 || ec) throw Error(failure("ffmpeg wrote nothing"));
  std::filesystem::remove(log_, ec);
}

}  // namespace spar::cli
