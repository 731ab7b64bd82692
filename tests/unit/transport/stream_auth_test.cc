#include "common/transport/stream_auth.h"

#include <cstdint>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "cutsim/v1/wire.pb.h"

namespace cutsim::transport {
namespace {

constexpr int64_t kOneSecond = 1'000'000'000;

SessionKey TestKey(char fill = 'a') {
  return ParseSessionKey(std::string(64, fill), "test");
}

std::vector<uint8_t> Serialise(const google::protobuf::MessageLite& m) {
  std::string s = m.SerializeAsString();
  return {s.begin(), s.end()};
}

std::vector<uint8_t> Signed(PayloadAuthenticator& auth, std::vector<uint8_t> body) {
  std::array<uint8_t, kTrailerBytes> trailer{};
  EXPECT_TRUE(auth.MakeTrailer(body, trailer));
  body.insert(body.end(), trailer.begin(), trailer.end());
  return body;
}

v1::HapticModel Model(uint64_t seq) {
  v1::HapticModel m;
  m.set_session("lab");
  m.set_seq(seq);
  m.mutable_f0()->set_x(0.25);
  return m;
}

TEST(PayloadAuthenticator, SignedBytesParseAndVerifyAndEveryAlterationIsForged) {
  PayloadAuthenticator sender(TestKey(), "cutsim.v1.HapticModel/hmac-sha256/1", "lab");
  PayloadAuthenticator receiver(TestKey(), "cutsim.v1.HapticModel/hmac-sha256/1", "lab");
  const std::vector<uint8_t> body = Serialise(Model(7));
  const std::vector<uint8_t> wire = Signed(sender, body);
  ASSERT_EQ(wire.size(), body.size() + kTrailerBytes);

  // A reader that knows nothing of the trailer still parses the message.
  v1::HapticModel parsed;
  ASSERT_TRUE(parsed.ParseFromArray(wire.data(), static_cast<int>(wire.size())));
  EXPECT_EQ(parsed.seq(), 7u);

  std::span<const uint8_t> covered;
  ASSERT_EQ(receiver.Check(wire, &covered), AuthVerdict::kOk);
  EXPECT_EQ(std::vector<uint8_t>(covered.begin(), covered.end()), body);

  // Flip every bit of the message in turn: never authentic.
  for (size_t i = 0; i < wire.size(); ++i) {
    for (int bit = 0; bit < 8; ++bit) {
      std::vector<uint8_t> bad = wire;
      bad[i] ^= static_cast<uint8_t>(1u << bit);
      const AuthVerdict v = receiver.Check(bad, &covered);
      EXPECT_TRUE(v == AuthVerdict::kForged || v == AuthVerdict::kUnsigned) << i << ":" << bit;
    }
  }
  EXPECT_EQ(receiver.Check(body, &covered), AuthVerdict::kUnsigned);
  EXPECT_EQ(receiver.Check({}, &covered), AuthVerdict::kUnsigned);
}

TEST(PayloadAuthenticator, TagsDoNotMoveAcrossKeysSessionsOrMessageKinds) {
  PayloadAuthenticator sender(TestKey(), "cutsim.v1.HapticModel/hmac-sha256/1", "lab");
  const std::vector<uint8_t> wire = Signed(sender, Serialise(Model(1)));
  std::span<const uint8_t> covered;
  PayloadAuthenticator other_key(TestKey('b'), "cutsim.v1.HapticModel/hmac-sha256/1", "lab");
  PayloadAuthenticator other_session(TestKey(), "cutsim.v1.HapticModel/hmac-sha256/1", "lab2");
  PayloadAuthenticator other_kind(TestKey(), "cutsim.v1.MeshDelta/hmac-sha256/1", "lab");
  EXPECT_EQ(other_key.Check(wire, &covered), AuthVerdict::kForged);
  EXPECT_EQ(other_session.Check(wire, &covered), AuthVerdict::kForged);
  EXPECT_EQ(other_kind.Check(wire, &covered), AuthVerdict::kForged);
}

TEST(EpochGate, AcceptsRisingSequencesAndRefusesReplaysAndFutureEpochs) {
  EpochGate gate(2 * kOneSecond, kOneSecond / 2);
  const int64_t t = 100 * kOneSecond;
  const uint64_t e = static_cast<uint64_t>(t - 10 * kOneSecond);
  EXPECT_EQ(gate.Offer(e, 1, t, t, t), AuthVerdict::kNewEpoch);
  EXPECT_EQ(gate.Offer(e, 3, t, t, t), AuthVerdict::kOk);
  EXPECT_EQ(gate.Offer(e, 3, t, t, t), AuthVerdict::kReplayed);
  EXPECT_EQ(gate.Offer(e, 2, t, t, t), AuthVerdict::kReplayed);
  // Epochs are start times: none after its own message, none zero.
  EXPECT_EQ(gate.Offer(~uint64_t{0}, 1, t, t, t), AuthVerdict::kInvalidEpoch);
  EXPECT_EQ(gate.Offer(static_cast<uint64_t>(t) + 1, 1, t, t, t), AuthVerdict::kInvalidEpoch);
  EXPECT_EQ(gate.Offer(0, 9, t, t, t), AuthVerdict::kInvalidEpoch);
  EXPECT_EQ(gate.epoch(), e);
  // Outside the window either way.
  EXPECT_EQ(gate.Offer(e, 4, t - 3 * kOneSecond, t, t), AuthVerdict::kOutsideWindow);
  EXPECT_EQ(gate.Offer(e, 4, t + 3 * kOneSecond, t, t), AuthVerdict::kOutsideWindow);
  EXPECT_EQ(gate.Offer(e, 4, t, t, t), AuthVerdict::kOk);

  // Without a window (observer streams replay old keyframes) only order counts.
  EpochGate open_window(0, kOneSecond / 2);
  EXPECT_EQ(open_window.Offer(e, 1, t - 1000 * kOneSecond + 2 * kOneSecond, t, t),
            AuthVerdict::kInvalidEpoch);  // signed before its epoch began
  EXPECT_EQ(open_window.Offer(e, 1, t + 1000 * kOneSecond, t, t), AuthVerdict::kNewEpoch);
}

TEST(EpochGate, ANewerSenderTakesOverButNeverLocksTheOlderOneOut) {
  EpochGate gate(0, kOneSecond / 2);
  const int64_t t = 100 * kOneSecond;
  const uint64_t genuine = static_cast<uint64_t>(t - 10 * kOneSecond);
  const uint64_t intruder = static_cast<uint64_t>(t - kOneSecond);
  EXPECT_EQ(gate.Offer(genuine, 1, t, t, t), AuthVerdict::kNewEpoch);
  // A newer epoch is a restarted sender: followed at once.
  EXPECT_EQ(gate.Offer(intruder, 1, t, t, t + 1), AuthVerdict::kNewEpoch);
  EXPECT_EQ(gate.epoch(), intruder);
  // The older sender is refused while the newer one is heard...
  EXPECT_EQ(gate.Offer(genuine, 2, t, t, t + kOneSecond / 4), AuthVerdict::kOtherSender);
  EXPECT_EQ(gate.Offer(intruder, 2, t, t, t + kOneSecond / 3), AuthVerdict::kOk);
  EXPECT_EQ(gate.Offer(genuine, 3, t, t, t + kOneSecond / 2), AuthVerdict::kOtherSender);
  // ...and follows again once the newer one has been quiet for the quiet period.
  const int64_t later = t + kOneSecond / 3 + kOneSecond / 2;
  EXPECT_EQ(gate.Offer(genuine, 4, t, t, later), AuthVerdict::kNewEpoch);
  EXPECT_EQ(gate.epoch(), genuine);
  // Its replay memory held through the detour, and so did the intruder's.
  EXPECT_EQ(gate.Offer(genuine, 4, t, t, later), AuthVerdict::kReplayed);
  EXPECT_EQ(gate.Offer(intruder, 2, t, t, later), AuthVerdict::kReplayed);
}

TEST(EpochGate, RefusedMessagesLeaveNoState) {
  EpochGate gate(0, kOneSecond / 2);
  const int64_t t = 100 * kOneSecond;
  const uint64_t followed = static_cast<uint64_t>(t);
  ASSERT_EQ(gate.Offer(followed, 50, t, t, t), AuthVerdict::kNewEpoch);
  // Thirty older epochs, each refused while the followed sender is heard.
  for (uint64_t i = 1; i <= 30; ++i) {
    EXPECT_EQ(gate.Offer(followed - i, 1, t, t, t), AuthVerdict::kOtherSender);
  }
  EXPECT_EQ(gate.Offer(followed, 50, t, t, t), AuthVerdict::kReplayed);
  EXPECT_EQ(gate.Offer(followed, 51, t, t, t), AuthVerdict::kOk);
}

TEST(EpochGate, LanesNumberIndependently) {
  EpochGate gate(0, kOneSecond);
  const int64_t t = 100 * kOneSecond;
  const uint64_t e = static_cast<uint64_t>(t);
  EXPECT_EQ(gate.Offer(e, 5, t, t, t, 0), AuthVerdict::kNewEpoch);
  EXPECT_EQ(gate.Offer(e, 5, t, t, t, 1), AuthVerdict::kOk);  // same seq, other lane
  EXPECT_EQ(gate.Offer(e, 5, t, t, t, 1), AuthVerdict::kReplayed);
  EXPECT_EQ(gate.Offer(e, 0, t, t, t, 2), AuthVerdict::kOk);  // seq 0 is a sequence like any
  EXPECT_EQ(gate.Offer(e, 0, t, t, t, 2), AuthVerdict::kReplayed);
  EXPECT_EQ(gate.Offer(e, 9, t, t, t, EpochGate::kLanes), AuthVerdict::kInvalidEpoch);
}

}  // namespace
}  // namespace cutsim::transport
