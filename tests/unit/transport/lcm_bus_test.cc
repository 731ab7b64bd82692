// LCM tests use memq:// only: it is in-process, so nothing touches a network
// interface at all (udpm would join a multicast group on the default-route
// interface of a host without a lo multicast route; see lcm_bus.h).

#include "common/transport/lcm_bus.h"

#include <chrono>
#include <stdexcept>
#include <string>
#include <vector>

#include <google/protobuf/util/message_differencer.h>
#include <gtest/gtest.h>

#include "common/core/error.h"
#include "common/transport/channels.h"
#include "cutsim/v1/wire.pb.h"
#include "tests/unit/transport/test_util.h"

namespace cutsim::transport {
namespace {

using google::protobuf::util::MessageDifferencer;

v1::ToolState Tool(const std::string& session, uint64_t seq) {
  v1::ToolState t;
  t.set_session(session);
  t.set_seq(seq);
  t.mutable_tip()->set_x(0.001 * static_cast<double>(seq));
  t.set_buttons(1);
  return t;
}

TEST(LcmBusTest, BadUrlsAreInputErrorsNotAborts) {
  for (const char* url : {"udpm://239.255.76.67:0", "udpm://239.255.76.67:65536", "udpm://239.255.76.67:-1",
                          "udpm://239.255.76.67:7667?ttl=256", "udpm://239.255.76.67:7667?ttl=x",
                          "udpm://10.0.0.1:7667", "udpm://239.255.76.67:7667?bogus=1", "tcpq://127.0.0.1:0",
                          "nosuch://x", "udpm:/x", ""}) {
    try {
      ValidateLcmUrl(url);
      ADD_FAILURE() << url << " accepted";
    } catch (const InputError& e) {
      EXPECT_EQ(e.source().field, "--lcm-url") << url;
    }
    EXPECT_THROW(LcmBus{url}, InputError) << url;
  }
  for (const char* url : {"udpm://239.255.76.67:7667?ttl=0", "udpm://239.255.76.67:7667?ttl=1&recv_buf_size=65536",
                          "memq://", "udpm://"}) {
    EXPECT_NO_THROW(ValidateLcmUrl(url)) << url;
  }
}

TEST(LcmBusTest, PublishSubscribeRoundTripOverMemq) {
  LcmBus bus("memq://");
  const std::string session = testing::UniqueSession("lcm");
  const std::string channel = LcmChannelName(session, LcmChannel::kTool);
  std::vector<v1::ToolState> got;
  auto sub = bus.Subscribe<v1::ToolState>(channel, [&](const v1::ToolState& t) { got.push_back(t); });
  const v1::ToolState sent = Tool(session, 1);
  EXPECT_EQ(bus.Publish(channel, sent), PublishStatus::kOk);
  EXPECT_EQ(bus.HandleTimeout(1000), 1);
  ASSERT_EQ(got.size(), 1U);
  EXPECT_TRUE(MessageDifferencer::Equals(got[0], sent));
  EXPECT_EQ(sub.stats().delivered, 1U);
  EXPECT_EQ(bus.stats().published, 1U);
  EXPECT_EQ(bus.received(), 1U);
}

TEST(LcmBusTest, StaleMessagesAreDroppedNotQueued) {
  LcmBus bus("memq://");
  const std::string session = testing::UniqueSession("lcm");
  const std::string channel = LcmChannelName(session, LcmChannel::kModel);
  std::vector<uint64_t> seqs;
  auto sub = bus.Subscribe<v1::HapticModel>(channel, [&](const v1::HapticModel& m) { seqs.push_back(m.seq()); });
  for (uint64_t seq = 1; seq <= 5; ++seq) {
    v1::HapticModel m;
    m.set_session(session);
    m.set_seq(seq);
    ASSERT_EQ(bus.Publish(channel, m), PublishStatus::kOk);
  }
  // One handling pass sees all five and delivers only the newest.
  EXPECT_EQ(bus.HandleTimeout(1000), 1);
  EXPECT_EQ(seqs, std::vector<uint64_t>{5});
  EXPECT_EQ(sub.stats().received, 5U);
  EXPECT_EQ(sub.stats().superseded, 4U);
  // Nothing left queued.
  EXPECT_EQ(bus.HandleTimeout(0), 0);
  EXPECT_EQ(seqs.size(), 1U);
}

TEST(LcmBusTest, SubscriptionsOnOtherChannelsAreIndependent) {
  LcmBus bus("memq://");
  const std::string session = testing::UniqueSession("lcm");
  int tools = 0;
  int models = 0;
  auto a = bus.Subscribe<v1::ToolState>(LcmChannelName(session, LcmChannel::kTool),
                                        [&](const v1::ToolState&) { ++tools; });
  auto b = bus.Subscribe<v1::HapticModel>(LcmChannelName(session, LcmChannel::kModel),
                                          [&](const v1::HapticModel&) { ++models; });
  ASSERT_EQ(bus.Publish(LcmChannelName(session, LcmChannel::kTool), Tool(session, 1)), PublishStatus::kOk);
  v1::HapticModel m;
  m.set_seq(1);
  ASSERT_EQ(bus.Publish(LcmChannelName(session, LcmChannel::kModel), m), PublishStatus::kOk);
  EXPECT_EQ(bus.HandleTimeout(1000), 2);
  EXPECT_EQ(tools, 1);
  EXPECT_EQ(models, 1);
}

TEST(LcmBusTest, GarbageIsCountedAndNeverDelivered) {
  LcmBus bus("memq://");
  const std::string channel = LcmChannelName(testing::UniqueSession("lcm"), LcmChannel::kTool);
  int calls = 0;
  auto sub = bus.Subscribe<v1::ToolState>(channel, [&](const v1::ToolState&) { ++calls; });
  const std::vector<uint8_t> garbage = {0x0a, 0xff, 0x01, 0x02};  // length 255 > remaining
  ASSERT_EQ(bus.PublishBytes(channel, garbage), PublishStatus::kOk);
  EXPECT_EQ(bus.HandleTimeout(1000), 0);
  EXPECT_EQ(calls, 0);
  EXPECT_EQ(sub.stats().decode_errors, 1U);
  EXPECT_EQ(bus.decode_errors(), 1U);
  const std::string msg = sub.last_error().Message();
  EXPECT_NE(msg.find(channel), std::string::npos) << msg;
  EXPECT_NE(msg.find("cutsim.v1.ToolState"), std::string::npos) << msg;
}

TEST(LcmBusTest, OversizedIncomingMessageIsDroppedWithoutCopy) {
  LcmBus bus("memq://", /*max_payload_bytes=*/1 << 20);  // a sender that allows more
  const std::string channel = LcmChannelName(testing::UniqueSession("lcm"), LcmChannel::kTool);
  int calls = 0;
  auto sub = bus.Subscribe<v1::ToolState>(channel, [&](const v1::ToolState&) { ++calls; });
  const std::vector<uint8_t> big(MaxPayloadBytes<v1::ToolState>() + 100, 0);
  ASSERT_EQ(bus.PublishBytes(channel, big), PublishStatus::kOk);
  bus.HandleTimeout(1000);
  EXPECT_EQ(calls, 0);
  EXPECT_EQ(sub.last_error().status, DecodeStatus::kTooLarge);
  EXPECT_NE(sub.last_error().Message().find("cutsim.v1.ToolState"), std::string::npos);
}

TEST(LcmBusTest, PublishRefusesMessagesAboveOneDatagram) {
  LcmBus bus("memq://");
  const std::string channel = LcmChannelName(testing::UniqueSession("lcm"), LcmChannel::kModel);
  int calls = 0;
  auto sub = bus.Subscribe<v1::HapticModel>(channel, [&](const v1::HapticModel&) { ++calls; });
  v1::HapticModel m;
  for (int i = 0; i < 400; ++i) m.mutable_stiffness()->add_m(1.0);  // 3.2 kB
  EXPECT_EQ(bus.Publish(channel, m), PublishStatus::kTooLarge);
  EXPECT_EQ(bus.stats().publish_too_large, 1U);
  EXPECT_EQ(bus.HandleTimeout(20), 0);
  EXPECT_EQ(calls, 0);
}

TEST(LcmBusTest, HandleTimeoutIsABoundedWait) {
  LcmBus bus("memq://");
  auto sub = bus.Subscribe<v1::ToolState>(LcmChannelName(testing::UniqueSession("lcm"), LcmChannel::kTool),
                                          [](const v1::ToolState&) {});
  const auto t0 = std::chrono::steady_clock::now();
  EXPECT_EQ(bus.HandleTimeout(30), 0);
  const auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_GE(ms, 20);
  EXPECT_LT(ms, 1000);
}

TEST(LcmBusTest, UnsubscribedChannelDeliversNothing) {
  LcmBus bus("memq://");
  const std::string session = testing::UniqueSession("lcm");
  const std::string channel = LcmChannelName(session, LcmChannel::kTool);
  int calls = 0;
  {
    auto sub = bus.Subscribe<v1::ToolState>(channel, [&](const v1::ToolState&) { ++calls; });
    ASSERT_EQ(bus.Publish(channel, Tool(session, 1)), PublishStatus::kOk);
    EXPECT_EQ(bus.HandleTimeout(1000), 1);
  }
  ASSERT_EQ(bus.Publish(channel, Tool(session, 2)), PublishStatus::kOk);
  EXPECT_EQ(bus.HandleTimeout(20), 0);
  EXPECT_EQ(calls, 1);
  EXPECT_EQ(bus.received(), 1U);  // counters of closed subscriptions are kept
}

TEST(LcmBusTest, CallbackExceptionLeavesHandleTimeoutAndTheBusKeepsWorking) {
  LcmBus bus("memq://");
  const std::string session = testing::UniqueSession("lcm");
  const std::string channel = LcmChannelName(session, LcmChannel::kTool);
  int calls = 0;
  auto sub = bus.Subscribe<v1::ToolState>(channel, [&](const v1::ToolState& t) {
    ++calls;
    if (t.seq() == 1) throw std::runtime_error("subscriber failed");
  });
  ASSERT_EQ(bus.Publish(channel, Tool(session, 1)), PublishStatus::kOk);
  EXPECT_THROW(bus.HandleTimeout(1000), std::runtime_error);
  ASSERT_EQ(bus.Publish(channel, Tool(session, 2)), PublishStatus::kOk);
  EXPECT_EQ(bus.HandleTimeout(1000), 1);
  EXPECT_EQ(calls, 2);
}

TEST(LcmBusTest, BadUrlThrowsInputErrorNamingTheFlag) {
  for (const char* url : {"", "nonsense", "bogus://x", "udpm://999.1.1.1:7667?ttl=0"}) {
    try {
      LcmBus bus(url);
      FAIL() << "no throw for " << url;
    } catch (const InputError& e) {
      EXPECT_EQ(e.source().field, "--lcm-url") << url;
      EXPECT_NE(std::string(e.what()).find(url), std::string::npos) << e.what();
    }
  }
}

TEST(LcmBusTest, ChannelsThatWouldBeRegexesAreRefused) {
  LcmBus bus("memq://");
  EXPECT_THROW(static_cast<void>(bus.Subscribe<v1::ToolState>("CUTSIM_.*", [](const v1::ToolState&) {})),
               InputError);
}

}  // namespace
}  // namespace cutsim::transport
