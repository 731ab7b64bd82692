#pragma once
/// @file
/// The process-wide stop request: signal handlers (SIGINT, SIGTERM) set it,
/// and every loop that can run long (the physics sub-steps of a frame, a
/// replay, a settle) polls it, so a stop is honoured within one sub-step,
/// not one frame.

#include <atomic>

namespace cutsim {

namespace internal {
inline std::atomic<bool> g_stop_requested{false};
static_assert(std::atomic<bool>::is_always_lock_free, "the stop flag is set from signal handlers");
}  // namespace internal

/// Asks every polling loop to stop. Async-signal-safe.
inline void RequestStop() noexcept { internal::g_stop_requested.store(true, std::memory_order_relaxed); }

/// True once `RequestStop` was called.
[[nodiscard]] inline bool StopRequested() noexcept {
  return internal::g_stop_requested.load(std::memory_order_relaxed);
}

}  // namespace cutsim
