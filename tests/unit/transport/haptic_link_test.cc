// The haptic link over memq:// (in-process LCM, no network at all).
#include "common/transport/haptic_link.h"

#include <atomic>
#include <cmath>
#include <limits>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "common/core/clock.h"
#include "common/transport/channels.h"
#include "common/transport/lcm_bus.h"
#include "common/transport/mailbox.h"
#include "tests/unit/transport/test_util.h"

namespace cutsim::transport {
namespace {

using Verdict = StreamSequencer::Verdict;

v1::ToolState Tool(const std::string& session, uint64_t seq, int64_t stamp_ns, double z = 0.01) {
  v1::ToolState t;
  t.set_session(session);
  t.set_seq(seq);
  t.set_stamp_ns(stamp_ns);
  t.mutable_tip()->set_z(z);
  t.mutable_blade_dir()->set_z(2.0);  // normalised by the link
  t.set_buttons(1);
  return t;
}

haptics::LocalModel Plane(double depth) {
  haptics::LocalModel m;
  m.contact = true;
  m.x0 = Eigen::Vector3d(0, 0, -depth);
  m.normal = Eigen::Vector3d::UnitZ();
  m.f0 = Eigen::Vector3d(0, 0, 1000.0 * depth);
  m.stiffness(2, 2) = 1000.0;
  return m;
}

TEST(StreamSequencerTest, ClassifiesByTable) {
  StreamSequencer s(/*restart_window=*/100);
  struct Row {
    uint64_t seq;
    int64_t stamp;
    Verdict expected;
  };
  const Row rows[] = {
      {10, 1000, Verdict::kAccepted},   // first
      {11, 1100, Verdict::kAccepted},   // newer
      {11, 1100, Verdict::kDuplicate},  // same again
      {9, 900, Verdict::kStale},        // reordered: older seq, older stamp
      {11, 1200, Verdict::kDuplicate},  // same seq even with a later stamp
      {13, 1050, Verdict::kAccepted},   // higher seq wins even with an odd stamp
      {1, 5000, Verdict::kRestart},     // restarted sender: low seq, later stamp
      {2, 5100, Verdict::kAccepted},
      {1, 5000, Verdict::kStale},       // the restart message again, late
  };
  for (const Row& r : rows) {
    EXPECT_EQ(s.Offer(r.seq, r.stamp), r.expected) << "seq " << r.seq << " stamp " << r.stamp;
  }
  // Far below the window counts as a restart whatever the stamp (another host's clock).
  StreamSequencer w(100);
  EXPECT_EQ(w.Offer(500, 10), Verdict::kAccepted);
  EXPECT_EQ(w.Offer(400, 0), Verdict::kStale);    // 100 below: within the window
  EXPECT_EQ(w.Offer(399, 0), Verdict::kRestart);  // 101 below: beyond it
}

TEST(HapticServerLinkTest, DropsStaleDuplicateForeignInvalidAndGarbageAndCountsThem) {
  LcmBus bus("memq://");
  const std::string session = testing::UniqueSession("hsl");
  const std::string channel = LcmChannelName(session, LcmChannel::kTool);
  HapticServerLink link(bus, session);
  EXPECT_FALSE(link.PollTool().has_value());

  // Each message is polled on its own: the bus delivers only the newest per pass.
  auto send_and_poll = [&](const v1::ToolState& t) {
    EXPECT_EQ(bus.Publish(channel, t), PublishStatus::kOk);
    return link.PollTool();
  };
  auto first = send_and_poll(Tool(session, 5, 5000));
  ASSERT_TRUE(first.has_value());
  EXPECT_EQ(first->seq, 5U);
  EXPECT_EQ(first->stamp_ns, 5000);
  EXPECT_GT(first->receive_ns, 0);
  EXPECT_NEAR(first->pose.blade_dir.z(), 1.0, 1e-15);
  EXPECT_EQ(first->buttons, 1U);

  EXPECT_FALSE(send_and_poll(Tool(session, 5, 5000)).has_value());       // duplicate
  EXPECT_FALSE(send_and_poll(Tool(session, 3, 3000)).has_value());       // out of order
  EXPECT_FALSE(send_and_poll(Tool("someone_else", 50, 9000)).has_value());  // foreign session
  EXPECT_FALSE(send_and_poll(Tool(session, 51, 9000, std::nan(""))).has_value());  // NaN tip
  EXPECT_FALSE(send_and_poll(Tool(session, 52, 9100, 1e6)).has_value());  // absurd position
  const std::vector<uint8_t> garbage = {0xff, 0xff, 0xff, 0xff, 0x0f, 0x01, 0x02};
  ASSERT_EQ(bus.PublishBytes(channel, garbage), PublishStatus::kOk);
  EXPECT_FALSE(link.PollTool().has_value());
  // The held pose is unchanged by all of that.
  ASSERT_TRUE(link.latest_tool().has_value());
  EXPECT_EQ(link.latest_tool()->seq, 5U);

  auto newer = send_and_poll(Tool(session, 6, 6000));
  ASSERT_TRUE(newer.has_value());
  EXPECT_EQ(newer->seq, 6U);
  auto restarted = send_and_poll(Tool(session, 1, 70000));  // client restarted: later stamp
  ASSERT_TRUE(restarted.has_value());
  EXPECT_EQ(restarted->seq, 1U);

  const HapticServerLinkStats s = link.stats();
  EXPECT_EQ(s.received, 9U);
  EXPECT_EQ(s.accepted, 3U);
  EXPECT_EQ(s.duplicate, 1U);
  EXPECT_EQ(s.stale, 1U);
  EXPECT_EQ(s.foreign_session, 1U);
  EXPECT_EQ(s.invalid, 2U);
  EXPECT_EQ(s.decode_errors, 1U);
  EXPECT_EQ(s.restarts, 1U);
}

TEST(HapticServerLinkTest, ReturnsOnlyTheNewestOfABurst) {
  LcmBus bus("memq://");
  const std::string session = testing::UniqueSession("hsl");
  const std::string channel = LcmChannelName(session, LcmChannel::kTool);
  HapticServerLink link(bus, session);
  for (uint64_t seq = 1; seq <= 10; ++seq) ASSERT_EQ(bus.Publish(channel, Tool(session, seq, 100 * seq)), PublishStatus::kOk);
  auto got = link.PollTool();
  ASSERT_TRUE(got.has_value());
  EXPECT_EQ(got->seq, 10U);
  EXPECT_EQ(link.stats().superseded, 9U);
  EXPECT_FALSE(link.PollTool().has_value());
}

TEST(HapticServerLinkTest, PublishesNumberedStampedModelsUnderOneDatagram) {
  LcmBus bus("memq://");
  const std::string session = testing::UniqueSession("hsl");
  std::vector<v1::HapticModel> got;
  auto sub = bus.Subscribe<v1::HapticModel>(LcmChannelName(session, LcmChannel::kModel),
                                            [&](const v1::HapticModel& m) { got.push_back(m); });
  HapticServerLink link(bus, session);
  haptics::LocalModel m = Plane(0.002);
  m.seq = 999;  // ignored: the link numbers the stream
  m.cut = {.cuts = 3, .cutting = true, .decay_per_second = 25.0};
  const int64_t before = MonotonicNs();
  link.PublishModel(m, 42);
  bus.HandleTimeout(100);
  link.PublishModel(m, 43);
  bus.HandleTimeout(100);
  ASSERT_EQ(got.size(), 2U);
  EXPECT_EQ(got[0].seq(), 1U);
  EXPECT_EQ(got[1].seq(), 2U);
  EXPECT_EQ(got[0].tool_seq(), 42U);
  EXPECT_EQ(got[0].session(), session);
  EXPECT_GE(got[0].stamp_ns(), before);
  EXPECT_LE(got[0].ByteSizeLong(), kLcmMaxPayloadBytes);
  haptics::LocalModel back;
  ASSERT_TRUE(FromProto(got[1], &back));
  EXPECT_EQ(back.cut.cuts, 3U);
  EXPECT_TRUE(back.cut.cutting);
  EXPECT_EQ(back.stiffness, m.stiffness);
  EXPECT_EQ(back.f0, m.f0);
  EXPECT_EQ(link.stats().models_published, 2U);
}

TEST(HapticLinkConversionTest, MalformedStiffnessIsRejected) {
  v1::HapticModel msg;
  msg.mutable_stiffness()->add_m(1.0);
  haptics::LocalModel m;
  EXPECT_FALSE(FromProto(msg, &m));
  msg.clear_stiffness();
  EXPECT_TRUE(FromProto(msg, &m));
  EXPECT_EQ(m.stiffness, Eigen::Matrix3d::Zero());
}

TEST(MailboxTest, ConsumerAlwaysSeesWholeValuesInOrderAndTheLastOne) {
  struct Value {
    uint64_t a = 0;
    uint64_t pad[14] = {};
    uint64_t b = 0;  // always ~a: a torn copy would break it
  };
  Mailbox<Value> box;
  constexpr uint64_t kN = 200000;
  std::atomic<bool> done{false};
  std::thread writer([&] {
    Value v;
    for (uint64_t i = 1; i <= kN; ++i) {
      v.a = i;
      v.b = ~i;
      box.Write(v);
    }
    done.store(true);
  });
  uint64_t last = 0;
  uint64_t reads = 0;
  Value got;
  for (;;) {
    const bool finished = done.load();
    while (box.Read(&got)) {
      ASSERT_EQ(got.b, ~got.a);
      ASSERT_GT(got.a, last);
      last = got.a;
      ++reads;
    }
    if (finished) break;
  }
  writer.join();
  EXPECT_EQ(last, kN);
  EXPECT_GT(reads, 0U);
  EXPECT_FALSE(box.Read(&got));
}

TEST(HapticClientLinkTest, HandsTheNewestModelToTheConsumerThreadAndSendsTools) {
  LcmBus bus("memq://");
  const std::string session = testing::UniqueSession("hcl");
  HapticServerLink server(bus, session);
  HapticClientLink client(bus, session);

  // The "haptic loop": publishes tool poses and takes models, on its own thread.
  constexpr uint64_t kModels = 300;
  std::atomic<bool> stop{false};
  std::atomic<uint64_t> last_seen{0};
  std::atomic<uint64_t> taken{0};
  std::atomic<bool> order_ok{true};
  std::thread loop([&] {
    transport::ReceivedModel rm;
    ToolSample tool;
    while (!stop.load()) {
      tool.pose.tip.z() = 0.001 * static_cast<double>(taken.load());
      client.PublishTool(tool);
      while (client.TakeModel(&rm)) {
        if (rm.model.seq <= last_seen.load()) order_ok.store(false);
        last_seen.store(rm.model.seq);
        taken.fetch_add(1);
      }
      std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
  });
  // The LCM side, driven from this thread (RunOnce instead of Start).
  uint64_t tools = 0;
  for (uint64_t i = 0; i < kModels; ++i) {
    client.RunOnce(0);
    if (auto t = server.PollTool()) ++tools;
    server.PublishModel(Plane(0.001), server.latest_tool() ? server.latest_tool()->seq : 0);
    client.RunOnce(0);
    if (i % 3 == 0) std::this_thread::sleep_for(std::chrono::microseconds(300));
  }
  const int64_t deadline = MonotonicNs() + 2'000'000'000;
  while (last_seen.load() < kModels && MonotonicNs() < deadline) {
    client.RunOnce(1);
    std::this_thread::yield();
  }
  stop.store(true);
  loop.join();
  EXPECT_TRUE(order_ok.load());
  EXPECT_EQ(last_seen.load(), kModels);  // the newest always arrives
  EXPECT_GT(taken.load(), 0U);
  EXPECT_LE(taken.load(), kModels);
  EXPECT_GT(tools, 0U);
  const HapticClientLinkStats s = client.stats();
  EXPECT_EQ(s.accepted, kModels);
  EXPECT_EQ(s.restarts, 0U);
  EXPECT_GT(s.tools_published, 0U);
  EXPECT_GE(server.stats().accepted, tools);  // the final RunOnce rounds dispatch tools too
}

TEST(HapticClientLinkTest, DropsForeignStaleAndGarbageModelsAndDetectsServerRestart) {
  LcmBus bus("memq://");
  const std::string session = testing::UniqueSession("hcl");
  const std::string channel = LcmChannelName(session, LcmChannel::kModel);
  HapticClientLink client(bus, session);
  v1::HapticModel captured;
  auto capture = bus.Subscribe<v1::HapticModel>(channel, [&](const v1::HapticModel& m) {
    if (m.seq() == 2) captured = m;
  });
  ReceivedModel rm;
  {
    HapticServerLink server(bus, session);
    for (int i = 0; i < 5; ++i) {
      server.PublishModel(Plane(0.001), 0);
      client.RunOnce(0);
    }
  }
  ASSERT_TRUE(client.TakeModel(&rm));
  EXPECT_EQ(rm.model.seq, 5U);
  EXPECT_EQ(rm.epoch, 0U);
  ASSERT_EQ(captured.seq(), 2U);

  // Replayed old model (out of order), foreign session, garbage, bad stiffness.
  ASSERT_EQ(bus.Publish(channel, captured), PublishStatus::kOk);
  client.RunOnce(0);
  v1::HapticModel foreign = captured;
  foreign.set_session("intruder");
  foreign.set_seq(100);
  ASSERT_EQ(bus.Publish(channel, foreign), PublishStatus::kOk);
  client.RunOnce(0);
  const std::vector<uint8_t> garbage = {0x0a, 0xff, 0x01};
  ASSERT_EQ(bus.PublishBytes(channel, garbage), PublishStatus::kOk);
  client.RunOnce(0);
  v1::HapticModel bad = captured;
  bad.set_seq(101);
  bad.mutable_stiffness()->add_m(1.0);
  ASSERT_EQ(bus.Publish(channel, bad), PublishStatus::kOk);
  client.RunOnce(0);
  EXPECT_FALSE(client.TakeModel(&rm));

  // A restarted server starts again at seq 1 with a later stamp.
  HapticServerLink restarted(bus, session);
  restarted.PublishModel(Plane(0.002), 0);
  client.RunOnce(0);
  ASSERT_TRUE(client.TakeModel(&rm));
  EXPECT_EQ(rm.model.seq, 1U);
  EXPECT_EQ(rm.epoch, 1U);

  const HapticClientLinkStats s = client.stats();
  EXPECT_EQ(s.stale, 1U);
  EXPECT_EQ(s.foreign_session, 1U);
  EXPECT_EQ(s.decode_errors, 1U);
  EXPECT_EQ(s.malformed, 1U);
  EXPECT_EQ(s.restarts, 1U);
  EXPECT_EQ(s.accepted, 6U);
}

TEST(HapticClientLinkTest, ReceiveFaultsDelayModels) {
  LcmBus bus("memq://");
  const std::string session = testing::UniqueSession("hcl");
  HapticLinkOptions options;
  options.receive_faults.delay_ms = 30.0;
  HapticClientLink client(bus, session, options);
  HapticServerLink server(bus, session);
  server.PublishModel(Plane(0.001), 0);
  const int64_t sent = MonotonicNs();
  ReceivedModel rm;
  while (!client.TakeModel(&rm) && MonotonicNs() - sent < 1'000'000'000) client.RunOnce(5);
  EXPECT_EQ(rm.model.seq, 1U);
  EXPECT_GE(rm.receive_ns - sent, 30'000'000);
  EXPECT_LT(rm.receive_ns - sent, 200'000'000);
}

TEST(HapticClientLinkTest, StartStopRunsTheLcmThread) {
  LcmBus bus("memq://");
  const std::string session = testing::UniqueSession("hcl");
  HapticClientLink client(bus, session);
  client.Start(1);
  ToolSample t;
  const uint64_t a = client.PublishTool(t);
  const uint64_t b = client.PublishTool(t);
  EXPECT_EQ(b, a + 1);
  const int64_t deadline = MonotonicNs() + 1'000'000'000;
  while (client.stats().tools_published == 0 && MonotonicNs() < deadline) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  client.Stop();
  client.Stop();  // idempotent
  EXPECT_GE(client.stats().tools_published, 1U);
  EXPECT_EQ(client.stats().tools_written, 2U);
}

// The LCM thread waits for an hour per round here: a pose can only reach the
// subscriber because PublishTool wakes the thread (eventfd), not because a
// poll timed out. The bounded waits below only turn a hang into a failure.
TEST(HapticClientLinkTest, PublishToolWakesTheLcmThreadInsteadOfWaitingForItsTimeout) {
  LcmBus bus("memq://");
  const std::string session = testing::UniqueSession("hcl");
  std::atomic<uint64_t> heard{0};
  std::atomic<uint64_t> last_seq{0};
  auto sub = bus.Subscribe<v1::ToolState>(LcmChannelName(session, LcmChannel::kTool), [&](const v1::ToolState& m) {
    last_seq.store(m.seq());
    heard.fetch_add(1);
  });
  HapticClientLink client(bus, session);
  constexpr int kHourMs = 3'600'000;
  client.Start(kHourMs);
  auto wait_until = [](const auto& done) {
    const int64_t guard = MonotonicNs() + 30'000'000'000;  // far below the hour
    while (!done() && MonotonicNs() < guard) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    return done();
  };
  auto wait_for = [&](uint64_t n) { return wait_until([&] { return heard.load() >= n; }); };
  // Once the thread has counted its first wait it is in (or entering) that
  // wait, with nothing to send: the pose can then only go out through the
  // wake-up.
  ASSERT_TRUE(wait_until([&] { return client.stats().waits >= 1; })) << "the LCM thread never began its wait";
  ToolSample t;
  const uint64_t first = client.PublishTool(t);
  ASSERT_TRUE(wait_for(1)) << "the pose waited for the LCM thread's timeout";
  EXPECT_EQ(last_seq.load(), first);
  const uint64_t second = client.PublishTool(t);
  ASSERT_TRUE(wait_for(2)) << "the second pose waited for the LCM thread's timeout";
  EXPECT_EQ(last_seq.load(), second);
  client.Stop();  // also woken: must not wait out the hour
  EXPECT_EQ(client.stats().tools_published, 2U);
  EXPECT_EQ(client.stats().tools_coalesced, 0U);
}

// With a receive thread the physics side never handles LCM: each pose is
// dispatched as it arrives and PollTool only takes the newest from a mailbox.
TEST(HapticServerLinkTest, ReceiveThreadHandsOverTheNewestPoseWithoutPolling) {
  LcmBus bus("memq://");
  const std::string session = testing::UniqueSession("hsl");
  const std::string channel = LcmChannelName(session, LcmChannel::kTool);
  HapticServerLink link(bus, session);
  link.StartReceiving();
  EXPECT_TRUE(link.receiving());
  auto wait_accepted = [&](uint64_t n) {
    const int64_t guard = MonotonicNs() + 30'000'000'000;
    while (link.stats().accepted < n && MonotonicNs() < guard) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    return link.stats().accepted >= n;
  };
  // Published from this thread while the receive thread handles the bus
  // (one publishing thread besides the handling one is allowed).
  for (uint64_t seq = 1; seq <= 5; ++seq) {
    ASSERT_EQ(bus.Publish(channel, Tool(session, seq, 100 * static_cast<int64_t>(seq), 0.001 * static_cast<double>(seq))),
              PublishStatus::kOk);
    ASSERT_TRUE(wait_accepted(seq)) << "pose " << seq << " was not dispatched by the receive thread";
  }
  auto got = link.PollTool();
  ASSERT_TRUE(got.has_value());
  EXPECT_EQ(got->seq, 5U);  // the newest, not the first since the last poll
  EXPECT_DOUBLE_EQ(got->pose.tip.z(), 0.005);
  EXPECT_GT(got->receive_ns, 0);
  EXPECT_FALSE(link.PollTool().has_value());
  // A stale pose is still dropped on the receive thread.
  ASSERT_EQ(bus.Publish(channel, Tool(session, 4, 400)), PublishStatus::kOk);
  const int64_t guard = MonotonicNs() + 30'000'000'000;
  while (link.stats().stale == 0 && MonotonicNs() < guard) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  EXPECT_EQ(link.stats().stale, 1U);
  EXPECT_FALSE(link.PollTool().has_value());
  // Models go out from this (the "physics") thread meanwhile.
  link.PublishModel(Plane(0.001), got->seq);
  EXPECT_EQ(link.stats().models_published, 1U);
  link.StopReceiving();
  link.StopReceiving();  // idempotent
  EXPECT_FALSE(link.receiving());
  EXPECT_EQ(link.stats().received, 6U);  // tool messages: 5 + the stale one
}

}  // namespace
}  // namespace cutsim::transport
