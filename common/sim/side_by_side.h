#pragma once
/// @file
/// Two phases of a cut step side by side: a task started beside the
/// calling thread and joined. With one thread the task runs at once on the
/// caller, so the phases follow each other in a fixed order; with two it
/// runs on a persistent worker thread (or on the caller, see below). The
/// phases a caller pairs read nothing the other writes, so every order gives
/// the same results bit for bit.
///
/// A cut step takes tens of microseconds, about what waking a sleeping
/// thread costs, so the worker spins briefly after each task (a cut step's
/// second pair follows its first closely) before it sleeps on the state
/// word; the caller spins while it joins. A task the worker has not taken
/// by the time the caller joins runs on the caller instead, so a descheduled
/// worker (a loaded machine) costs a step its serial time, not a scheduler
/// wake-up. Nothing allocates per task.

#include <atomic>
#include <exception>
#include <thread>
#include <utility>

namespace cutsim::sim {

/// A non-owning reference to a callable `void()`; the callable must outlive
/// its run.
class TaskRef {
 public:
  TaskRef() = default;
  template <typename F>
  explicit TaskRef(F& f) : object_(&f), call_([](void* o) { (*static_cast<F*>(o))(); }) {}
  void operator()() const { call_(object_); }

 private:
  void* object_ = nullptr;
  void (*call_)(void*) = nullptr;
};

class SideBySide {
 public:
  /// `two_threads`: run started tasks on a worker thread (else at once here).
  explicit SideBySide(bool two_threads);
  ~SideBySide();
  SideBySide(const SideBySide&) = delete;
  SideBySide& operator=(const SideBySide&) = delete;

  [[nodiscard]] bool two_threads() const { return worker_.joinable(); }

  /// Starts `task` beside the caller; one task at a time, joined before
  /// the next.
  void Start(TaskRef task);
  /// Waits for the started task (nothing if none) and rethrows what it threw.
  void Join();

  /// `beside` and `here` side by side: with one thread, `beside` first.
  /// Joined even when `here` throws.
  template <typename Beside, typename Here>
  void Run(Beside& beside, Here&& here) {
    Start(TaskRef(beside));
    JoinGuard guard(*this);
    std::forward<Here>(here)();
    guard.Join();
  }

  /// Joins on scope exit, for a caller whose code between Start and Join
  /// may throw (the task may reference the caller's frame).
  class JoinGuard {
   public:
    explicit JoinGuard(SideBySide& lanes) : lanes_(lanes) {}
    ~JoinGuard() {
      if (!joined_) lanes_.Wait();
    }
    JoinGuard(const JoinGuard&) = delete;
    JoinGuard& operator=(const JoinGuard&) = delete;
    /// Joins now (rethrowing the task's exception).
    void Join() {
      joined_ = true;
      lanes_.Join();
    }

   private:
    SideBySide& lanes_;
    bool joined_ = false;
  };

 private:
  enum State : int { kIdle, kQueued, kRunning, kDone, kStop };
  void Wait();     // until the started task has finished, without rethrowing
  void RunTask();  // task_() on this thread, its exception kept in error_
  void WorkerLoop();

  std::atomic<int> state_{kIdle};
  bool started_ = false;  // a task was started and not yet joined (caller's side)
  TaskRef task_;
  std::exception_ptr error_;
  std::thread worker_;
};

}  // namespace cutsim::sim
