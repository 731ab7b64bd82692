// Fault injector statistics with fixed seeds: every number here is a property
// of the seeded generator, so the tolerances are statistical (≥ 5σ) and the
// test is deterministic.
#include "common/transport/fault_injection.h"

#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "common/core/error.h"
#include "common/transport/channels.h"
#include "common/transport/lcm_bus.h"
#include "cutsim/v1/wire.pb.h"
#include "tests/unit/transport/test_util.h"

namespace cutsim::transport {
namespace {

constexpr int64_t kMs = 1'000'000;

std::vector<uint8_t> Payload(uint32_t i) {
  std::vector<uint8_t> b(4);
  std::memcpy(b.data(), &i, 4);
  return b;
}

uint32_t Id(std::span<const uint8_t> b) {
  uint32_t i = 0;
  std::memcpy(&i, b.data(), 4);
  return i;
}

/// Submits `n` messages 1 ms apart, releasing as time advances; returns the
/// ids in release order and the release delays.
struct RunResult {
  std::vector<uint32_t> order;
  std::vector<int64_t> delay_ns;
  FaultStats stats;
};
RunResult RunStream(const FaultConfig& config, uint32_t n) {
  FaultInjector injector(config, 4096);
  RunResult r;
  std::vector<int64_t> sent(n);
  int64_t now = 0;
  auto sink = [&](std::span<const uint8_t> b) {
    const uint32_t id = Id(b);
    r.order.push_back(id);
    r.delay_ns.push_back(now - sent[id]);
  };
  // Time advances in 0.1 ms polls; one message per ms.
  for (uint32_t i = 0; i < n; ++i) {
    for (int k = 0; k < 10; ++k) {
      now = int64_t{i} * kMs + k * (kMs / 10);
      if (k == 0) {
        sent[i] = now;
        const auto p = Payload(i);
        injector.Submit(p, now);
      }
      injector.Release(now, sink);
    }
  }
  for (int k = 0; k < 20000 && injector.in_flight() > 0; ++k) {
    now += kMs / 10;
    injector.Release(now, sink);
  }
  r.stats = injector.stats();
  return r;
}

TEST(FaultInjectionTest, PassThroughWhenInactive) {
  const RunResult r = RunStream(FaultConfig{}, 1000);
  ASSERT_EQ(r.order.size(), 1000U);
  for (uint32_t i = 0; i < 1000; ++i) EXPECT_EQ(r.order[i], i);
  for (int64_t d : r.delay_ns) EXPECT_EQ(d, 0);
}

TEST(FaultInjectionTest, DropRatioMatchesTheProbability) {
  FaultConfig c;
  c.drop = 0.1;
  c.seed = 42;
  const RunResult r = RunStream(c, 100000);
  const double ratio = static_cast<double>(r.stats.dropped) / 100000.0;
  EXPECT_NEAR(ratio, 0.1, 0.005);  // σ ≈ 0.00095
  EXPECT_EQ(r.order.size(), 100000U - r.stats.dropped);
  EXPECT_EQ(r.stats.released, r.order.size());
}

TEST(FaultInjectionTest, DelayIsFixedPlusUniformJitter) {
  FaultConfig c;
  c.delay_ms = 50.0;
  c.jitter_ms = 10.0;
  c.seed = 7;
  const RunResult r = RunStream(c, 20000);
  ASSERT_EQ(r.order.size(), 20000U);
  double sum = 0.0;
  int below_mid = 0;
  for (int64_t d : r.delay_ns) {
    // Released by a poll every 0.1 ms: up to 0.1 ms after the due time.
    EXPECT_GE(d, 50 * kMs);
    EXPECT_LE(d, 60 * kMs + kMs / 10);
    sum += static_cast<double>(d);
    if (d < 55 * kMs) ++below_mid;
  }
  const double mean_ms = sum / 20000.0 / 1e6;
  EXPECT_NEAR(mean_ms, 55.05, 0.15);  // uniform jitter mean 5 ms (+ ≤ 0.1 ms poll), σ_mean ≈ 0.02 ms
  EXPECT_NEAR(below_mid / 20000.0, 0.5, 0.02);
  EXPECT_GE(r.stats.min_delay_ns, 50 * kMs);
  EXPECT_LE(r.stats.max_delay_ns, 60 * kMs);
  // 1 ms spacing with 10 ms of jitter reorders messages.
  int inversions = 0;
  for (size_t i = 1; i < r.order.size(); ++i) inversions += r.order[i] < r.order[i - 1] ? 1 : 0;
  EXPECT_GT(inversions, 1000);
}

TEST(FaultInjectionTest, DuplicatesMatchTheProbability) {
  FaultConfig c;
  c.duplicate = 0.2;
  c.seed = 3;
  const RunResult r = RunStream(c, 50000);
  EXPECT_NEAR(static_cast<double>(r.stats.duplicated) / 50000.0, 0.2, 0.01);
  EXPECT_EQ(r.order.size(), 50000U + r.stats.duplicated);
}

TEST(FaultInjectionTest, ReorderHoldsMessagesBackSoLaterOnesOvertake) {
  FaultConfig c;
  c.reorder = 0.1;
  c.reorder_ms = 5.0;
  c.seed = 11;
  const RunResult r = RunStream(c, 20000);
  ASSERT_EQ(r.order.size(), 20000U);
  EXPECT_NEAR(static_cast<double>(r.stats.reordered) / 20000.0, 0.1, 0.01);
  // Each held message is overtaken by the next ~5 (1 ms apart), so it
  // arrives after a higher id: count messages released after a higher one.
  uint32_t highest = 0;
  int late = 0;
  for (uint32_t id : r.order) {
    if (id < highest) ++late;
    highest = std::max(highest, id);
  }
  EXPECT_NEAR(late, static_cast<int>(r.stats.reordered), static_cast<int>(r.stats.reordered) / 20 + 5);
  for (int64_t d : r.delay_ns) EXPECT_TRUE(d < kMs / 10 + 1 || (d >= 5 * kMs && d <= 5 * kMs + kMs / 10));
}

TEST(FaultInjectionTest, SameSeedSameFates) {
  FaultConfig c;
  c.delay_ms = 2.0;
  c.jitter_ms = 3.0;
  c.drop = 0.2;
  c.duplicate = 0.1;
  c.reorder = 0.1;
  c.seed = 99;
  const RunResult a = RunStream(c, 5000);
  const RunResult b = RunStream(c, 5000);
  EXPECT_EQ(a.order, b.order);
  EXPECT_EQ(a.delay_ns, b.delay_ns);
  c.seed = 100;
  EXPECT_NE(RunStream(c, 5000).order, a.order);
}

TEST(FaultInjectionTest, FullScheduleDropsAndCounts) {
  FaultConfig c;
  c.delay_ms = 100.0;
  FaultInjector injector(c, 8);
  const auto p = Payload(1);
  for (int i = 0; i < 10; ++i) injector.Submit(p, 0);
  EXPECT_EQ(injector.in_flight(), 8U);
  EXPECT_EQ(injector.stats().overflow, 2U);
  std::vector<uint8_t> big(FaultInjector::kMaxMessageBytes + 1);
  EXPECT_EQ(injector.Submit(big, 0), 0);
  EXPECT_EQ(injector.next_due_ns(), 100 * kMs);
}

TEST(FaultInjectionTest, InvalidSettingsNameTheFlag) {
  auto message = [](FaultConfig c) {
    try {
      ValidateFaultConfig(c);
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  FaultConfig c;
  c.drop = 1.5;
  EXPECT_NE(message(c).find("--fault-drop"), std::string::npos);
  c = {};
  c.delay_ms = -1.0;
  EXPECT_NE(message(c).find("--fault-delay-ms"), std::string::npos);
  c = {};
  c.jitter_ms = std::nan("");
  EXPECT_NE(message(c).find("--fault-jitter-ms"), std::string::npos);
  c = {};
  c.duplicate = -0.1;
  EXPECT_NE(message(c).find("--fault-dup"), std::string::npos);
  EXPECT_EQ(message(FaultConfig{}), "");
}

TEST(FaultInjectionTest, FaultyPublisherSendsDelayedMessagesFromPoll) {
  LcmBus bus("memq://");
  const std::string channel = LcmChannelName(testing::UniqueSession("fault"), LcmChannel::kTool);
  std::vector<uint64_t> got;
  auto sub = bus.Subscribe<v1::ToolState>(channel, [&](const v1::ToolState& t) { got.push_back(t.seq()); });
  FaultConfig c;
  c.delay_ms = 5.0;
  FaultyLcmPublisher pub(bus, channel, c);
  v1::ToolState t;
  t.set_seq(1);
  ASSERT_EQ(pub.Publish(t, 0), PublishStatus::kOk);
  EXPECT_EQ(pub.Poll(4 * kMs), 0);
  bus.HandleTimeout(0);
  EXPECT_TRUE(got.empty());
  EXPECT_EQ(pub.Poll(5 * kMs), 1);
  bus.HandleTimeout(100);
  EXPECT_EQ(got, std::vector<uint64_t>{1});
}

}  // namespace
}  // namespace cutsim::transport
