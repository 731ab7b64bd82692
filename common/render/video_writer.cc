#include "common/render/video_writer.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string_view>
#include <system_error>
#include <vector>

#include "common/core/error.h"
#include "common/core/log.h"

extern char** environ;

namespace cutsim::render {
namespace {

std::string ErrnoText(int error) { return std::generic_category().message(error); }

/// True when the PATH entry `dir` holds an executable `ffmpeg`.
bool IsExecutableIn(std::string_view dir) {
  const std::string candidate = fmt::format("{}/ffmpeg", dir.empty() ? "." : dir);
  return ::access(candidate.c_str(), X_OK) == 0;
}

/// libx264 when this ffmpeg was built with it, else the always-present mpeg4.
/// Asked once per process (`ffmpeg -encoders` starts a process).
const std::string& ChooseCodec() {
  static const std::string codec = [] {
    std::FILE* pipe = ::popen("ffmpeg -hide_banner -encoders 2>/dev/null", "r");
    if (pipe == nullptr) return std::string("mpeg4");
    std::string text;
    char chunk[4096];
    size_t n = 0;
    while ((n = std::fread(chunk, 1, sizeof chunk, pipe)) > 0) text.append(chunk, n);
    ::pclose(pipe);
    return std::string(text.find(" libx264 ") != std::string::npos ? "libx264" : "mpeg4");
  }();
  return codec;
}

/// Writes all of `data` to `fd`. Returns 0 or the errno of the failure.
/// SIGPIPE is blocked on this thread for the duration and any SIGPIPE we
/// caused is consumed, so a dead ffmpeg gives EPIPE instead of killing us.
int WriteAll(int fd, const uint8_t* data, size_t size) {
  sigset_t pipe_set;
  sigset_t old_set;
  sigemptyset(&pipe_set);
  sigaddset(&pipe_set, SIGPIPE);
  sigset_t pending;
  sigpending(&pending);
  const bool was_pending = sigismember(&pending, SIGPIPE) == 1;
  pthread_sigmask(SIG_BLOCK, &pipe_set, &old_set);
  int error = 0;
  while (size > 0) {
    const ssize_t n = ::write(fd, data, size);
    if (n < 0) {
      if (errno == EINTR) continue;
      error = errno;
      break;
    }
    data += n;
    size -= static_cast<size_t>(n);
  }
  if (error == EPIPE && !was_pending) {
    const timespec no_wait{0, 0};
    sigtimedwait(&pipe_set, nullptr, &no_wait);
  }
  pthread_sigmask(SIG_SETMASK, &old_set, nullptr);
  return error;
}

}  // namespace

bool FfmpegVideoWriter::Available() {
  const char* path = std::getenv("PATH");
  if (path == nullptr) return false;
  std::string_view rest(path);
  while (true) {
    const size_t colon = rest.find(':');
    if (IsExecutableIn(rest.substr(0, colon))) return true;
    if (colon == std::string_view::npos) return false;
    rest.remove_prefix(colon + 1);
  }
}

FfmpegVideoWriter::FfmpegVideoWriter(std::filesystem::path path, int width, int height, double fps)
    : path_(std::move(path)),
      width_(width),
      height_(height),
      uncaught_at_start_(std::uncaught_exceptions()) {
  const std::string name = path_.string();
  if (!path_.has_extension() || !path_.has_stem()) {
    ThrowFileError(name,
                   "a video file needs a name with an extension (.mp4, .mkv, .avi) "
                   "to choose the container");
  }
  if (width < 1 || height < 1 || width > 16384 || height > 16384) {
    ThrowFileError(name,
                   fmt::format("video size {}x{} is outside [1, 16384] pixels", width, height));
  }
  if (!(fps > 0.0 && fps <= 1000.0)) {
    ThrowFileError(name, fmt::format("frame rate {} is outside (0, 1000] frames/s", fps));
  }
  if (!Available()) ThrowFileError(name, "cannot write a video: no ffmpeg executable on PATH");
  codec_ = ChooseCodec();
  tmp_path_ = path_;
  tmp_path_.replace_filename(
      fmt::format("{}.tmp{}", path_.stem().string(), path_.extension().string()));

  std::vector<std::string> args = {
      "ffmpeg", "-hide_banner", "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgba",
      "-s", fmt::format("{}x{}", width, height), "-r", fmt::format("{}", fps), "-i", "-", "-an",
      // yuv420p needs even sizes: pad odd ones by one pixel.
      "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-c:v", codec_, "-pix_fmt", "yuv420p"};
  if (codec_ == "libx264") {
    args.insert(args.end(), {"-preset", "veryfast", "-crf", "18"});
  } else {
    args.insert(args.end(), {"-q:v", "2"});
  }
  args.push_back(tmp_path_.string());
  std::vector<char*> argv;
  for (std::string& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);

  int fds[2];
  if (::pipe2(fds, O_CLOEXEC) != 0) {
    ThrowFileError(name, fmt::format("cannot create a pipe to ffmpeg: {}", ErrnoText(errno)));
  }
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_adddup2(&actions, fds[0], STDIN_FILENO);  // dup2 clears O_CLOEXEC
  const int spawn_error = posix_spawnp(&pid_, "ffmpeg", &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  ::close(fds[0]);
  if (spawn_error != 0) {
    ::close(fds[1]);
    pid_ = -1;
    ThrowFileError(name, fmt::format("cannot start ffmpeg: {}", ErrnoText(spawn_error)));
  }
  pipe_fd_ = fds[1];
}

FfmpegVideoWriter::~FfmpegVideoWriter() {
  if (pid_ < 0) return;
  const bool unwinding = std::uncaught_exceptions() > uncaught_at_start_;
  try {
    Finish(/*commit=*/!unwinding);
  } catch (const std::exception& e) {
    Log().error("{}", e.what());
  }
}

void FfmpegVideoWriter::WriteFrame(const Image& frame) {
  const std::string name = path_.string();
  if (pid_ < 0) ThrowFileError(name, "video already closed");
  if (frame.width != width_ || frame.height != height_ || !frame.valid()) {
    ThrowFileError(name, fmt::format("frame is {}x{}, the video is {}x{}", frame.width,
                                     frame.height, width_, height_));
  }
  if (write_failed_) ThrowFileError(name, "ffmpeg stopped reading frames");
  if (const int error = WriteAll(pipe_fd_, frame.rgba.data(), frame.rgba.size()); error != 0) {
    write_failed_ = true;
    ThrowFileError(name, fmt::format("ffmpeg stopped reading frames: {}", ErrnoText(error)));
  }
  ++frames_written_;
}

void FfmpegVideoWriter::Close() { Finish(/*commit=*/true); }

void FfmpegVideoWriter::Finish(bool commit) {
  if (pid_ < 0) return;
  if (pipe_fd_ >= 0) {
    ::close(pipe_fd_);  // EOF: ffmpeg flushes and exits
    pipe_fd_ = -1;
  }
  int status = 0;
  pid_t waited = 0;
  do {
    waited = ::waitpid(pid_, &status, 0);
  } while (waited < 0 && errno == EINTR);
  pid_ = -1;
  const std::string name = path_.string();
  std::error_code ec;
  const bool ffmpeg_ok = waited > 0 && WIFEXITED(status) && WEXITSTATUS(status) == 0;
  if (!commit || !ffmpeg_ok || write_failed_) {
    std::filesystem::remove(tmp_path_, ec);
    if (!commit) return;
    if (waited > 0 && WIFEXITED(status)) {
      ThrowFileError(name, fmt::format("ffmpeg exited with status {} after {} frames",
                                       WEXITSTATUS(status), frames_written_));
    }
    ThrowFileError(name,
                   fmt::format("ffmpeg did not finish normally after {} frames", frames_written_));
  }
  std::filesystem::rename(tmp_path_, path_, ec);
  if (ec) {
    std::filesystem::remove(tmp_path_, ec);
    ThrowFileError(name,
                   fmt::format("cannot move {} into place: {}", tmp_path_.string(), ec.message()));
  }
}

}  // namespace cutsim::render
