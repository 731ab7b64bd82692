#include "common/core/clock.h"

#include <gtest/gtest.h>

namespace cutsim {
namespace {

TEST(ClockTest, MonotonicNeverGoesBackwards) {
  int64_t prev = MonotonicNs();
  for (int i = 0; i < 10000; ++i) {
    const int64_t now = MonotonicNs();
    ASSERT_GE(now, prev);
    prev = now;
  }
}

TEST(ClockTest, SleepUntilReachesDeadline) {
  const int64_t deadline = MonotonicNs() + 2'000'000;  // 2 ms
  SleepUntilNs(deadline);
  EXPECT_GE(MonotonicNs(), deadline);  // never early; lateness is a benchmark matter
}

// A deadline already past returns without sleeping. The bound is loose (a
// loaded machine may deschedule the thread), yet far below the 1 s a sleep
// for the deadline's distance would take.
TEST(ClockTest, SleepUntilPastDeadlineReturnsPromptly) {
  for (const int64_t past_ns : {int64_t{1'000'000}, int64_t{1'000'000'000}}) {
    const int64_t start = MonotonicNs();
    SleepUntilNs(start - past_ns);
    EXPECT_LT(MonotonicNs() - start, 250'000'000) << past_ns;
  }
  const int64_t start = MonotonicNs();
  SleepUntilNs(0);  // the clock's origin
  EXPECT_LT(MonotonicNs() - start, 250'000'000);
}

}  // namespace
}  // namespace cutsim
