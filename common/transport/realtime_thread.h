#pragma once
/// @file
/// Real-time scheduling of cutsim's threads, in one place: SCHED_FIFO for the
/// threads on the haptic link's latency path (the client's servo loop and LCM
/// thread, the server's physics and LCM receive threads), memory locking for
/// the servo loop, and the governor that keeps a busy SCHED_FIFO loop from
/// starving the rest of the machine. The priorities are ordered so that the
/// 1 kHz haptic loop always wins:
///
///   haptic loop 80 (`cutsim-haptic --rt-priority`) > LCM threads 70 >
///   server physics 60 > everything else (SCHED_OTHER).
///
/// The LCM threads do microseconds of work per message, so running them
/// above the physics lets a pose or model through while a frame computes.
/// Raising priority needs CAP_SYS_NICE or an rtprio limit; when it is not
/// permitted the thread keeps its normal policy and a warning says so.

#include <pthread.h>
#include <sched.h>

#include <cstdint>
#include <string>
#include <string_view>

namespace cutsim::transport {

inline constexpr int kHapticLoopPriority = 80;     ///< The haptic servo loop (default).
inline constexpr int kLcmThreadPriority = 70;      ///< LCM send/receive threads (both ends).
inline constexpr int kServerPhysicsPriority = 60;  ///< The server's real-time physics loop.

/// Sets the calling thread to SCHED_FIFO at `priority` (1..99). Returns 0 or
/// the error number (EPERM when not permitted). Never throws.
int SetCurrentThreadFifo(int priority) noexcept;

/// Returns the calling thread to SCHED_OTHER. Returns 0 or the error number.
int SetCurrentThreadNormal() noexcept;

/// Sets the calling thread to SCHED_FIFO at `priority`; when that is not
/// permitted, logs a warning naming `thread` and what a normal thread risks
/// (`delays`, e.g. "poses and models") and returns false. `priority` ≤ 0
/// does nothing and returns false.
bool RaiseCurrentThread(int priority, std::string_view thread, std::string_view delays);

/// CPU time the calling thread has used, ns (CLOCK_THREAD_CPUTIME_ID).
[[nodiscard]] int64_t ThreadCpuNs() noexcept;

/// Runs the calling thread at SCHED_FIFO `priority` for its scope (or until
/// `Restore`), then restores its previous policy. Threads created inside the
/// scope inherit the priority (pthreads' default PTHREAD_INHERIT_SCHED): this
/// is how the receive thread LCM's udpm provider starts on the first
/// subscription is given the LCM priority. Does nothing for `priority` ≤ 0
/// and, silently, when not permitted.
class ScopedThreadFifo {
 public:
  explicit ScopedThreadFifo(int priority) noexcept;
  ~ScopedThreadFifo() { Restore(); }
  ScopedThreadFifo(const ScopedThreadFifo&) = delete;
  ScopedThreadFifo& operator=(const ScopedThreadFifo&) = delete;
  /// Restores the previous policy now (idempotent).
  void Restore() noexcept;
  [[nodiscard]] bool raised() const { return raised_; }

 private:
  int old_policy_ = SCHED_OTHER;
  sched_param old_param_{};
  bool raised_ = false;
};

/// What `TryEnableRealtime` achieved.
struct RealtimeStatus {
  bool fifo = false;     ///< The thread runs SCHED_FIFO.
  bool mlocked = false;  ///< All current and future memory is locked.
};

/// Locks memory (mlockall) and switches the calling thread to SCHED_FIFO
/// `priority`, each when permitted; logs a clear warning for what was not.
/// For a loop that must never page-fault or wait behind normal threads.
RealtimeStatus TryEnableRealtime(int priority, std::string_view thread);

/// Touches 256 KiB of stack so that a loop running after it never faults a
/// new stack page (with memory locked, the pages then stay).
void PrefaultStack() noexcept;

/// Keeps a SCHED_FIFO loop that cannot keep up from starving the normal
/// threads on its core (and from running into the kernel's RT throttling at
/// 95 %, which would also stall a haptic loop on that core). Once per window
/// it compares the thread's own CPU time (not wall time, which includes
/// preemption) with the wall time: above `max_busy` the thread goes back to
/// SCHED_OTHER, below `resume_busy` it returns to SCHED_FIFO. Lives on the
/// governed thread; `Update` allocates nothing and makes one clock call per
/// window.
class FifoGovernor {
 public:
  struct Limits {
    int64_t window_ns = 1'000'000'000;  ///< ns between decisions.
    double max_busy = 0.9;              ///< Busy fraction above which FIFO is dropped.
    double resume_busy = 0.7;           ///< Busy fraction below which FIFO returns.
  };

  /// Switches the calling thread to SCHED_FIFO `priority` (warning naming
  /// `thread` and `delays` when not permitted, see `RaiseCurrentThread`).
  /// `priority` ≤ 0: governs nothing and the thread stays as it is.
  FifoGovernor(int priority, std::string_view thread, std::string_view delays, Limits limits);
  FifoGovernor(int priority, std::string_view thread, std::string_view delays)
      : FifoGovernor(priority, thread, delays, Limits{}) {}

  /// Call once per loop iteration with the current monotonic time, ns.
  void Update(int64_t now_ns);

  /// The thread runs SCHED_FIFO now.
  [[nodiscard]] bool fifo() const { return fifo_; }
  /// SCHED_FIFO was permitted at the start (so the governor is active).
  [[nodiscard]] bool permitted() const { return permitted_; }

 private:
  int priority_;
  std::string thread_;
  Limits limits_;
  bool permitted_ = false;
  bool fifo_ = false;
  int64_t window_start_ns_ = 0;
  int64_t window_cpu_start_ns_ = 0;
};

}  // namespace cutsim::transport
