#pragma once
/// @file
/// Monotonic time for pacing loops and measuring durations. Never the wall
/// clock: it jumps.

#include <cstdint>

namespace cutsim {

/// Nanoseconds on CLOCK_MONOTONIC.
int64_t MonotonicNs();

/// Seconds on CLOCK_MONOTONIC, as double.
double MonotonicSeconds();

/// Sleeps until the absolute CLOCK_MONOTONIC time `deadline_ns`
/// (clock_nanosleep TIMER_ABSTIME, resumed after signals). Does not allocate.
void SleepUntilNs(int64_t deadline_ns);

/// Measures an interval: construct, then read `ElapsedSeconds()`.
class Stopwatch {
 public:
  Stopwatch() : start_ns_(MonotonicNs()) {}
  void Reset() { start_ns_ = MonotonicNs(); }
  [[nodiscard]] int64_t ElapsedNs() const { return MonotonicNs() - start_ns_; }
  [[nodiscard]] double ElapsedSeconds() const { return 1e-9 * static_cast<double>(ElapsedNs()); }

 private:
  int64_t start_ns_;
};

}  // namespace cutsim
