// Scheduling helpers that must behave the same whether or not this machine
// permits SCHED_FIFO: priority 0 means "leave the thread alone", a scope
// restores what it changed, and the governor never acts when FIFO was not
// granted.

#include "common/transport/realtime_thread.h"

#include <pthread.h>
#include <sched.h>

#include <chrono>
#include <cmath>
#include <cstdint>
#include <thread>

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

// The thread's CPU clock advances while it works and not while it sleeps.
// Work is measured until the clock has advanced (or 5 s of wall time have
// passed), so a loaded machine that deschedules the thread cannot fail it.
TEST(RealtimeThreadTest, ThreadCpuTimeGrowsWithWork) {
  const int64_t cpu0 = ThreadCpuNs();
  const int64_t start = MonotonicNs();
  volatile double x = 1.0;
  while (ThreadCpuNs() - cpu0 < 2'000'000 && MonotonicNs() - start < 5'000'000'000) x = std::sqrt(x + 1.0);
  EXPECT_GE(ThreadCpuNs() - cpu0, 2'000'000);
  const int64_t cpu1 = ThreadCpuNs();
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  EXPECT_LT(ThreadCpuNs() - cpu1, 20'000'000) << "the thread's CPU clock ran while it slept";
}

}  // namespace
}  // namespace cutsim::transport
