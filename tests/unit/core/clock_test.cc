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

TEST(ClockTest, SleepUntilPastDeadlineReturns) {
  SleepUntilNs(MonotonicNs() - 1'000'000);
  SUCCEED();
}

}  // namespace
}  // namespace cutsim
