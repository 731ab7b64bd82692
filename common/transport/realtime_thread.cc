#include "common/transport/realtime_thread.h"

#include <sys/mman.h>
#include <time.h>

#include <cerrno>
#include <cstring>

#include "common/core/clock.h"
#include "common/core/log.h"

namespace cutsim::transport {

int SetCurrentThreadFifo(int priority) noexcept {
  sched_param param{};
  param.sched_priority = priority;
  return pthread_setschedparam(pthread_self(), SCHED_FIFO, &param);
}

int SetCurrentThreadNormal() noexcept {
  sched_param param{};
  param.sched_priority = 0;
  return pthread_setschedparam(pthread_self(), SCHED_OTHER, &param);
}

bool RaiseCurrentThread(int priority, std::string_view thread, std::string_view delays) {
  if (priority <= 0) return false;
  const int rc = SetCurrentThreadFifo(priority);
  if (rc == 0) return true;
  Log().warn("SCHED_FIFO priority {} not permitted for the {} ({}): it runs as a normal thread and "
             "other load can delay {} (grant CAP_SYS_NICE or an rtprio limit in "
             "/etc/security/limits.conf, or run with --no-rt to silence this)",
             priority, thread, std::strerror(rc), delays);
  return false;
}

int64_t ThreadCpuNs() noexcept {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<int64_t>(ts.tv_sec) * 1'000'000'000 + ts.tv_nsec;
}

// ---------------------------------------------------------------------------
// ScopedThreadFifo

ScopedThreadFifo::ScopedThreadFifo(int priority) noexcept {
  if (priority <= 0) return;
  if (pthread_getschedparam(pthread_self(), &old_policy_, &old_param_) != 0) return;
  raised_ = SetCurrentThreadFifo(priority) == 0;
}

void ScopedThreadFifo::Restore() noexcept {
  if (raised_) pthread_setschedparam(pthread_self(), old_policy_, &old_param_);
  raised_ = false;
}

// ---------------------------------------------------------------------------
// Memory

RealtimeStatus TryEnableRealtime(int priority, std::string_view thread) {
  RealtimeStatus status;
  if (mlockall(MCL_CURRENT | MCL_FUTURE) == 0) {
    status.mlocked = true;
  } else {
    Log().warn("mlockall failed ({}): memory is not locked, a page fault can stall the {} "
               "(raise RLIMIT_MEMLOCK, e.g. `ulimit -l unlimited`, or grant CAP_IPC_LOCK)",
               std::strerror(errno), thread);
  }
  status.fifo = RaiseCurrentThread(priority, thread, "it");
  return status;
}

void PrefaultStack() noexcept {
  constexpr size_t kBytes = 256 * 1024;
  [[maybe_unused]] volatile unsigned char buffer[kBytes];
  for (size_t i = 0; i < kBytes; i += 4096) buffer[i] = 0;
}

// ---------------------------------------------------------------------------
// FifoGovernor

FifoGovernor::FifoGovernor(int priority, std::string_view thread, std::string_view delays,
                           Limits limits)
    : priority_(priority), thread_(thread), limits_(limits) {
  permitted_ = RaiseCurrentThread(priority, thread, delays);
  fifo_ = permitted_;
  window_start_ns_ = MonotonicNs();
  window_cpu_start_ns_ = ThreadCpuNs();
}

void FifoGovernor::Update(int64_t now_ns) {
  if (!permitted_ || now_ns - window_start_ns_ < limits_.window_ns) return;
  const int64_t cpu_ns = ThreadCpuNs();
  const double busy = static_cast<double>(cpu_ns - window_cpu_start_ns_) /
                      static_cast<double>(now_ns - window_start_ns_);
  if (fifo_ && busy > limits_.max_busy) {
    fifo_ = false;
    (void)SetCurrentThreadNormal();
    Log().warn("the {} used {:.0f}% of a core over the last {:.3g} s: SCHED_OTHER until it needs "
               "less than {:.0f}%, so it cannot starve other threads",
               thread_, 100.0 * busy, 1e-9 * static_cast<double>(limits_.window_ns),
               100.0 * limits_.resume_busy);
  } else if (!fifo_ && busy < limits_.resume_busy) {
    fifo_ = SetCurrentThreadFifo(priority_) == 0;
    if (fifo_) Log().info("the {} used {:.0f}% of a core: back to SCHED_FIFO", thread_, 100.0 * busy);
  }
  window_start_ns_ = now_ns;
  window_cpu_start_ns_ = cpu_ns;
}

}  // namespace cutsim::transport
