// Scheduling helpers that must behave the same whether or not this machine
// permits SCHED_FIFO: priority 0 means "leave the thread alone", a scope
// restores what it changed, and the governor never acts when FIFO was not
// granted.

#include "common/transport/realtime_thread.h"

#include <pthread.h>
#include <sched.h>

#include <cmath>
#include <cstdint>

#include <gtest/gtest.h>

#include "common/core/clock.h"

namespace cutsim::transport {
namespace {

int CurrentPolicy() {
  int policy = -1;
  sched_param param{};
  pthread_getschedparam(pthread_self(), &policy, &param);
  return policy;
}

TEST(RealtimeThreadTest, PriorityZeroLeavesTheThreadAlone) {
  const int before = CurrentPolicy();
  {
    ScopedThreadFifo scope(0);
    EXPECT_FALSE(scope.raised());
    EXPECT_EQ(CurrentPolicy(), before);
  }
  EXPECT_FALSE(RaiseCurrentThread(0, "test thread", "nothing"));
  EXPECT_EQ(CurrentPolicy(), before);
  FifoGovernor governor(0, "test thread", "nothing");
  EXPECT_FALSE(governor.permitted());
  EXPECT_FALSE(governor.fifo());
  governor.Update(MonotonicNs() + 10'000'000'000);
  EXPECT_FALSE(governor.fifo());
  EXPECT_EQ(CurrentPolicy(), before);
}

TEST(RealtimeThreadTest, ScopeRestoresThePolicyItRaised) {
  const int before = CurrentPolicy();
  {
    ScopedThreadFifo scope(kLcmThreadPriority);
    EXPECT_EQ(CurrentPolicy(), scope.raised() ? SCHED_FIFO : before);
    scope.Restore();
    EXPECT_EQ(CurrentPolicy(), before);
    EXPECT_FALSE(scope.raised());
  }
  EXPECT_EQ(CurrentPolicy(), before);
}

TEST(RealtimeThreadTest, GovernorDropsFifoForABusyThread) {
  // Meaningful only where SCHED_FIFO is permitted; elsewhere the governor
  // must stay inactive.
  FifoGovernor governor(1, "test thread", "nothing",
                        {.window_ns = 20'000'000, .max_busy = 0.5, .resume_busy = 0.1});
  if (!governor.permitted()) {
    EXPECT_FALSE(governor.fifo());
    GTEST_SKIP() << "SCHED_FIFO not permitted here";
  }
  EXPECT_EQ(CurrentPolicy(), SCHED_FIFO);
  const int64_t start = MonotonicNs();
  volatile double x = 1.0;
  while (MonotonicNs() - start < 40'000'000) x = std::sqrt(x + 1.0);  // busy: ~100 %
  governor.Update(MonotonicNs());
  EXPECT_FALSE(governor.fifo());
  EXPECT_EQ(CurrentPolicy(), SCHED_OTHER);
  (void)SetCurrentThreadNormal();
}

TEST(RealtimeThreadTest, ThreadCpuTimeGrowsWithWork) {
  const int64_t cpu0 = ThreadCpuNs();
  const int64_t start = MonotonicNs();
  volatile double x = 1.0;
  while (MonotonicNs() - start < 5'000'000) x = std::sqrt(x + 1.0);
  EXPECT_GT(ThreadCpuNs() - cpu0, 1'000'000);
}

}  // namespace
}  // namespace cutsim::transport
