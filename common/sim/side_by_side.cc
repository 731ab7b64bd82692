#include "common/sim/side_by_side.h"

namespace cutsim::sim {
namespace {

void SpinPause() {
#if defined(__x86_64__) || defined(__i386__)
  __builtin_ia32_pause();
#endif
}

// Pauses the worker spins for a next task before it sleeps (tens of
// microseconds), and the caller spins per yield while the worker runs a task.
constexpr int kWorkerSpins = 4096;
constexpr int kJoinSpinsPerYield = 1024;

}  // namespace

SideBySide::SideBySide(bool two_threads) {
  if (two_threads) worker_ = std::thread([this] { WorkerLoop(); });
}

SideBySide::~SideBySide() {
  if (!worker_.joinable()) return;
  Wait();
  state_.store(kStop, std::memory_order_release);
  state_.notify_one();
  worker_.join();
}

void SideBySide::Start(TaskRef task) {
  started_ = true;
  error_ = nullptr;
  if (!worker_.joinable()) {
    try {
      task();
    } catch (...) {
      error_ = std::current_exception();
    }
    return;
  }
  task_ = task;
  state_.store(kQueued, std::memory_order_release);
  state_.notify_one();
}

void SideBySide::Wait() {
  if (!started_) return;
  started_ = false;
  if (!worker_.joinable()) return;
  // A worker that has not taken the task yet (descheduled on a loaded
  // machine, or still waking) loses it: the caller runs it here, so a step
  // never waits for the scheduler to give the worker a core.
  int queued = kQueued;
  if (state_.compare_exchange_strong(queued, kRunning, std::memory_order_acq_rel)) {
    RunTask();
    state_.store(kIdle, std::memory_order_release);
    return;
  }
  for (int spins = 1; state_.load(std::memory_order_acquire) != kDone; ++spins) {
    SpinPause();
    if (spins % kJoinSpinsPerYield == 0) std::this_thread::yield();
  }
  state_.store(kIdle, std::memory_order_relaxed);
}

void SideBySide::RunTask() {
  try {
    task_();
  } catch (...) {
    error_ = std::current_exception();
  }
}

void SideBySide::Join() {
  Wait();
  if (error_) std::rethrow_exception(std::exchange(error_, nullptr));
}

void SideBySide::WorkerLoop() {
  for (;;) {
    int s = state_.load(std::memory_order_acquire);
    for (int spin = 0; s != kQueued && s != kStop && spin < kWorkerSpins; ++spin) {
      SpinPause();
      s = state_.load(std::memory_order_acquire);
    }
    if (s == kStop) return;
    if (s != kQueued) {
      state_.wait(s, std::memory_order_acquire);  // until the caller changes the state
      continue;
    }
    // Take the task unless the caller took it first (Wait).
    if (!state_.compare_exchange_strong(s, kRunning, std::memory_order_acq_rel)) continue;
    RunTask();
    state_.store(kDone, std::memory_order_release);
  }
}

}  // namespace cutsim::sim
