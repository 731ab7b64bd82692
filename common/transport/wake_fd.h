#pragma once
/// @file
/// RAII over a non-blocking Linux eventfd, used to wake a helper thread that
/// waits in `poll` (e.g. the haptic client's LCM thread) from a real-time
/// thread. `Notify` is one non-blocking `write` of 8 bytes: it never blocks,
/// allocates or throws, so the 1 kHz loop may call it after filling a
/// `Mailbox`. Several notifications before the waiter runs coalesce into one
/// wake-up (the eventfd counter just adds up).

#include <sys/eventfd.h>
#include <unistd.h>

#include <cerrno>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>

namespace cutsim::transport {

/// A wake-up channel between threads of one process.
class WakeFd {
 public:
  /// Throws `std::runtime_error` if the kernel refuses an eventfd.
  WakeFd() : fd_(::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC)) {
    if (fd_ < 0) throw std::runtime_error(std::string("eventfd: ") + std::strerror(errno));
  }
  ~WakeFd() {
    if (fd_ >= 0) ::close(fd_);
  }
  WakeFd(const WakeFd&) = delete;
  WakeFd& operator=(const WakeFd&) = delete;

  /// Wakes the waiter (any thread; wait-free apart from the system call).
  void Notify() noexcept {
    const uint64_t one = 1;
    // EAGAIN only if the counter would overflow 2^64 − 2: a wake-up is pending anyway.
    [[maybe_unused]] const ssize_t n = ::write(fd_, &one, sizeof(one));
  }

  /// Waiter side: consumes pending notifications; true if there were any.
  bool Drain() noexcept {
    uint64_t count = 0;
    return ::read(fd_, &count, sizeof(count)) == static_cast<ssize_t>(sizeof(count)) && count > 0;
  }

  /// The descriptor to `poll` for POLLIN.
  [[nodiscard]] int fd() const { return fd_; }

 private:
  int fd_ = -1;
};

}  // namespace cutsim::transport
