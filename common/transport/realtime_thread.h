#pragma once
/// @file
/// SCHED_FIFO for the threads on the haptic link's latency path (the
/// client's LCM thread, the server's physics and LCM receive threads). The
/// priorities are ordered so that the 1 kHz haptic loop always wins:
///
///   haptic loop 80 (`cutsim-haptic --rt-priority`) > LCM threads 70 >
///   server physics 60 > everything else (SCHED_OTHER).
///
/// The LCM threads do microseconds of work per message, so running them
/// above the physics lets a pose or model through while a frame computes.
/// Raising priority needs CAP_SYS_NICE or an rtprio limit; when it is not
/// permitted the thread keeps its normal policy and the caller logs a warning.

#include <pthread.h>
#include <sched.h>

namespace cutsim::transport {

inline constexpr int kLcmThreadPriority = 70;      ///< LCM send/receive threads (both ends).
inline constexpr int kServerPhysicsPriority = 60;  ///< The server's real-time physics loop.

/// Sets the calling thread to SCHED_FIFO at `priority` (1..99). Returns 0 or
/// the error number (EPERM when not permitted). Never throws.
inline int SetCurrentThreadFifo(int priority) noexcept {
  sched_param param{};
  param.sched_priority = priority;
  return pthread_setschedparam(pthread_self(), SCHED_FIFO, &param);
}

/// Returns the calling thread to SCHED_OTHER. Returns 0 or the error number.
inline int SetCurrentThreadNormal() noexcept {
  sched_param param{};
  param.sched_priority = 0;
  return pthread_setschedparam(pthread_self(), SCHED_OTHER, &param);
}

/// Runs the calling thread at SCHED_FIFO `priority` for its scope, then
/// restores its previous policy. Threads created inside the scope inherit
/// the priority (pthreads' default PTHREAD_INHERIT_SCHED): this is how the
/// receive thread LCM's udpm provider starts on the first subscription is
/// given the LCM priority. Silently does nothing when not permitted.
class ScopedThreadFifo {
 public:
  explicit ScopedThreadFifo(int priority) noexcept {
    if (pthread_getschedparam(pthread_self(), &old_policy_, &old_param_) != 0) return;
    raised_ = SetCurrentThreadFifo(priority) == 0;
  }
  ~ScopedThreadFifo() {
    if (raised_) pthread_setschedparam(pthread_self(), old_policy_, &old_param_);
  }
  ScopedThreadFifo(const ScopedThreadFifo&) = delete;
  ScopedThreadFifo& operator=(const ScopedThreadFifo&) = delete;
  [[nodiscard]] bool raised() const { return raised_; }

 private:
  int old_policy_ = SCHED_OTHER;
  sched_param old_param_{};
  bool raised_ = false;
};

}  // namespace cutsim::transport
