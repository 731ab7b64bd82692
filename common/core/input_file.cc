#include "common/core/input_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <new>
#include <utility>

#include <fmt/format.h>

namespace cutsim {
namespace {

std::string KindOf(mode_t mode) {
  if (S_ISDIR(mode)) return "a directory";
  if (S_ISCHR(mode)) return "a character device";
  if (S_ISBLK(mode)) return "a block device";
  if (S_ISFIFO(mode)) return "a pipe";
  if (S_ISSOCK(mode)) return "a socket";
  return "not a regular file";
}

/// Every output is written beside itself and renamed over its path, which
/// would replace whatever is there: an existing path (or what a link at it
/// points to) must be a regular file.
void RequireRegularOrAbsent(const std::string& path, std::string_view what) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0 || S_ISREG(st.st_mode)) return;
  ThrowFileError(path, fmt::format("cannot write the {}: it is {}; cutsim writes a new file and renames it over the "
                                   "path, which would replace it (give the path of a regular file or a new one)",
                                   what, KindOf(st.st_mode)));
}

/// Closes a file descriptor on scope exit.
class FdCloser {
 public:
  explicit FdCloser(int fd) : fd_(fd) {}
  ~FdCloser() {
    if (fd_ >= 0) ::close(fd_);
  }
  FdCloser(const FdCloser&) = delete;
  FdCloser& operator=(const FdCloser&) = delete;
  int get() const { return fd_; }
  int Release() { return std::exchange(fd_, -1); }

 private:
  int fd_;
};

}  // namespace

uint64_t CheckInputFile(const std::string& path, std::string_view what, uint64_t max_bytes) {
  if (path.empty()) ThrowInputError(SourceRef{.field = std::string(what)}, "no file given (empty path)");
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    ThrowFileError(path, fmt::format("cannot open the {}: {}", what, std::strerror(errno)));
  }
  if (!S_ISREG(st.st_mode)) {
    ThrowFileError(path, fmt::format("the {} is {}: only regular files are read", what, KindOf(st.st_mode)));
  }
  const auto size = static_cast<uint64_t>(st.st_size);
  if (size > max_bytes) {
    ThrowFileError(path, fmt::format("the {} has {} bytes, more than the limit of {} bytes", what, size, max_bytes));
  }
  return size;
}

std::string ReadInputFile(const std::string& path, std::string_view what, uint64_t max_bytes) {
  const uint64_t size = CheckInputFile(path, what, max_bytes);
  FdCloser fd(::open(path.c_str(), O_RDONLY | O_CLOEXEC));
  if (fd.get() < 0) ThrowFileError(path, fmt::format("cannot open the {}: {}", what, std::strerror(errno)));
  std::string text;
  try {
    text.resize(static_cast<size_t>(size));
  } catch (const std::bad_alloc&) {
    ThrowFileError(path, fmt::format("out of memory reading the {} ({} bytes)", what, size));
  }
  size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::read(fd.get(), text.data() + done, text.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) ThrowFileError(path, fmt::format("read error in the {}: {}", what, std::strerror(errno)));
    if (n == 0) break;  // the file shrank while being read
    done += static_cast<size_t>(n);
  }
  text.resize(done);
  return text;
}

void RequireCountFits(int64_t count, int64_t min_bytes_each, uint64_t bytes_left, const SourceRef& where,
                      std::string_view what) {
  if (count < 0) ThrowInputError(where, fmt::format("{} {} is negative", what, count));
  if (min_bytes_each > 0 &&
      static_cast<uint64_t>(count) > bytes_left / static_cast<uint64_t>(min_bytes_each)) {
    ThrowInputError(where, fmt::format("{} {} cannot fit in the {} bytes left in the file (each needs at least {}): "
                                       "truncated file or wrong count",
                                       what, count, bytes_left, min_bytes_each));
  }
}

void CheckOutputPath(const std::string& path, std::string_view what) {
  if (path.empty()) ThrowInputError(SourceRef{.field = std::string(what)}, "no file given (empty path)");
  RequireRegularOrAbsent(path, what);
  struct stat st {};
  if (::stat(path.c_str(), &st) == 0 && ::access(path.c_str(), W_OK) != 0) {
    ThrowFileError(path, fmt::format("cannot write the {}: {}", what, std::strerror(errno)));
  }
  // Files are written beside themselves and renamed into place: the
  // directory must be writable too.
  std::filesystem::path dir = std::filesystem::path(path).parent_path();
  if (dir.empty()) dir = ".";
  struct stat dst {};
  if (::stat(dir.c_str(), &dst) != 0 || !S_ISDIR(dst.st_mode)) {
    ThrowFileError(path, fmt::format("cannot write the {}: directory {} does not exist", what, dir.string()));
  }
  if (::access(dir.c_str(), W_OK | X_OK) != 0) {
    ThrowFileError(path, fmt::format("cannot write the {}: directory {} is not writable: {}", what, dir.string(),
                                     std::strerror(errno)));
  }
}

void WriteFileAtomically(const std::string& path, std::string_view content) {
  RequireRegularOrAbsent(path, "output");
  const std::string tmp = path + ".tmp";
  auto fail = [&](std::string_view step) {
    const int err = errno;
    ::unlink(tmp.c_str());
    ThrowFileError(path, fmt::format("{} failed: {}", step, std::strerror(err)));
  };
  {
    FdCloser fd(::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644));
    if (fd.get() < 0) ThrowFileError(path, fmt::format("cannot create {}: {}", tmp, std::strerror(errno)));
    size_t done = 0;
    while (done < content.size()) {
      const ssize_t n = ::write(fd.get(), content.data() + done, content.size() - done);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) fail("write");
      done += static_cast<size_t>(n);
    }
    if (::fsync(fd.get()) != 0) fail("fsync");
    if (::close(fd.Release()) != 0) fail("close");
  }
  if (::rename(tmp.c_str(), path.c_str()) != 0) fail(fmt::format("rename of {}", tmp));
}

}  // namespace cutsim
