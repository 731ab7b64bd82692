// Signed local models over memq:// (haptic_link.h): the server's link signs,
// the client's link lets only authentic, fresh models of the followed server
// into the mailbox and counts every refusal by its reason.
#include <chrono>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "common/core/clock.h"
#include "common/transport/channels.h"
#include "common/transport/codec.h"
#include "common/transport/haptic_link.h"
#include "common/transport/lcm_bus.h"
#include "tests/unit/transport/test_util.h"

namespace cutsim::transport {
namespace {

constexpr char kKeyHex[] = "8f1c2e3d4a5b6c7d8e9fa0b1c2d3e4f5061728394a5b6c7d8e9fa0b1c2d3e4f5";
constexpr char kWrongKeyHex[] = "00112233445566778899aabbccddeeff00112233445566778899aabbccddeeff";

haptics::LocalModel Push(double newtons) {
  haptics::LocalModel m;
  m.contact = true;
  m.normal = Eigen::Vector3d::UnitZ();
  m.f0 = Eigen::Vector3d(0, 0, newtons);
  m.valid_for = 0.01;
  return m;
}

class ModelAuthTest : public ::testing::Test {
 protected:
  ModelAuthTest()
      : session_(testing::UniqueSession("mauth")),
        key_(ParseSessionKey(kKeyHex, "test")),
        checker_(key_, kHapticModelDomain, session_),
        signer_(key_, kHapticModelDomain, session_),
        client_(bus_, session_, {.model_auth = &checker_}) {
    capture_ = bus_.SubscribeRaw(LcmChannelName(session_, LcmChannel::kModel), 4096,
                                 [this](std::span<const uint8_t> b) { captured_.emplace_back(b.begin(), b.end()); });
  }

  /// Runs the client's LCM thread body once and returns the newest model taken, if any.
  std::optional<ReceivedModel> Deliver() {
    client_.RunOnce(0);
    ReceivedModel m;
    if (!client_.TakeModel(&m)) return std::nullopt;
    return m;
  }
  void PublishRaw(std::span<const uint8_t> bytes) {
    ASSERT_EQ(bus_.PublishBytes(LcmChannelName(session_, LcmChannel::kModel), bytes), PublishStatus::kOk);
  }
  uint64_t Count(PacketReason r) const { return client_.stats().packets[r]; }

  LcmBus bus_{"memq://"};
  std::string session_;
  SessionKey key_;
  PayloadAuthenticator checker_;
  PayloadAuthenticator signer_;
  HapticClientLink client_;
  LcmSubscription capture_;
  std::vector<std::vector<uint8_t>> captured_;
};

TEST_F(ModelAuthTest, OnlyAuthenticFreshModelsReachTheMailbox) {
  HapticServerLink server(bus_, session_, {.model_auth = &signer_});
  ASSERT_TRUE(server.signs_models());
  server.PublishModel(Push(0.26), 1);
  const auto genuine = Deliver();
  ASSERT_TRUE(genuine.has_value());
  EXPECT_NEAR(genuine->model.f0.z(), 0.26, 1e-12);
  ASSERT_EQ(captured_.size(), 1U);
  const std::vector<uint8_t> signed_bytes = captured_.back();

  // Unsigned: the same model without its trailer.
  PublishRaw(std::span<const uint8_t>(signed_bytes.data(), signed_bytes.size() - kTrailerBytes));
  EXPECT_FALSE(Deliver().has_value());
  EXPECT_EQ(Count(PacketReason::kUnsigned), 1U);

  // Forged: an 8 N push signed with another key.
  PayloadAuthenticator intruder(ParseSessionKey(kWrongKeyHex, "test"), kHapticModelDomain, session_);
  HapticServerLink fake(bus_, session_, {.model_auth = &intruder});
  fake.PublishModel(Push(8.0), 1);
  EXPECT_FALSE(Deliver().has_value());
  EXPECT_EQ(Count(PacketReason::kForged), 1U);

  // A tampered byte of a genuine model is forged too.
  std::vector<uint8_t> tampered = signed_bytes;
  tampered[tampered.size() / 2] ^= 0x40;
  PublishRaw(tampered);
  EXPECT_FALSE(Deliver().has_value());
  EXPECT_EQ(Count(PacketReason::kForged), 2U);

  // Replayed: the genuine bytes again.
  PublishRaw(signed_bytes);
  EXPECT_FALSE(Deliver().has_value());
  EXPECT_EQ(Count(PacketReason::kReplayed), 1U);

  // The genuine server goes on.
  server.PublishModel(Push(0.27), 2);
  const auto next = Deliver();
  ASSERT_TRUE(next.has_value());
  EXPECT_NEAR(next->model.f0.z(), 0.27, 1e-12);
  const PacketCounts c = client_.stats().packets;
  EXPECT_EQ(c[PacketReason::kAccepted], 2U);
  EXPECT_FALSE(c.packet_level);  // memq: per LCM delivery
  EXPECT_TRUE(client_.authenticates_models());
}

TEST_F(ModelAuthTest, ARestartedServerIsFollowedAndAnOlderOneIsRefused) {
  // Epochs are the links' start times: `older` starts first.
  HapticServerLink older(bus_, session_, {.model_auth = &signer_});
  std::this_thread::sleep_for(std::chrono::milliseconds(2));
  PayloadAuthenticator signer2(key_, kHapticModelDomain, session_);
  HapticServerLink current(bus_, session_, {.model_auth = &signer2});
  current.PublishModel(Push(0.26), 1);
  ASSERT_TRUE(Deliver().has_value());
  // A second, older server publishing the session is refused while `current` is alive.
  older.PublishModel(Push(8.0), 1);
  EXPECT_FALSE(Deliver().has_value());
  EXPECT_EQ(Count(PacketReason::kOtherSender), 1U);
  // A restarted server (newer epoch, seq back to 1) is followed at once.
  std::this_thread::sleep_for(std::chrono::milliseconds(2));
  PayloadAuthenticator signer3(key_, kHapticModelDomain, session_);
  HapticServerLink restarted(bus_, session_, {.model_auth = &signer3});
  restarted.PublishModel(Push(0.3), 1);
  const auto m = Deliver();
  ASSERT_TRUE(m.has_value());
  EXPECT_NEAR(m->model.f0.z(), 0.3, 1e-12);
  EXPECT_EQ(m->epoch, 1U);  // the renderer resets on a new server
  EXPECT_EQ(client_.stats().restarts, 1U);
  // The previous one is now the other sender.
  current.PublishModel(Push(0.26), 2);
  EXPECT_FALSE(Deliver().has_value());
  EXPECT_EQ(Count(PacketReason::kOtherSender), 2U);
}

TEST_F(ModelAuthTest, SignedModelsFitOneDatagramAndCarryEpochAndSigningTime) {
  HapticServerLink server(bus_, session_, {.model_auth = &signer_});
  haptics::LocalModel m = Push(0.26);
  m.stiffness.setConstant(1e3);
  server.PublishModel(m, 1);
  ASSERT_TRUE(Deliver().has_value());
  ASSERT_EQ(captured_.size(), 1U);
  EXPECT_LE(captured_.back().size(), kLcmMaxPayloadBytes);
  const auto split = SplitTrailer(captured_.back());
  EXPECT_EQ(split.tag.size(), HmacSha256::kTagBytes);
  // The body parses as a HapticModel carrying epoch and signing time.
  v1::HapticModel parsed;
  ASSERT_TRUE(DecodeInto(split.body, parsed, "test"));
  EXPECT_GT(parsed.epoch(), 0U);
  EXPECT_GE(static_cast<uint64_t>(parsed.wall_ns()), parsed.epoch());
  EXPECT_TRUE(parsed.hmac().empty());
}

}  // namespace
}  // namespace cutsim::transport
