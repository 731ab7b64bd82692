// The debrief's control channel over an in-process loopback DDS domain: a
// keyed server takes only commands signed with its session key, each once;
// unsigned, forged and oversized ones are counted, never delivered.
#include "common/transport/debrief_control.h"

#include <chrono>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "common/transport/codec.h"
#include "tests/unit/transport/test_util.h"

namespace cutsim::transport {
namespace {

using namespace std::chrono_literals;

SessionKey Key(uint8_t fill) {
  SessionKey k;
  k.size = 32;
  k.bytes.fill(fill);
  return k;
}

/// Waits until `writer` sees a reader (discovery is asynchronous even in
/// one process).
bool Matched(const DebriefControlWriter& writer) {
  const auto end = std::chrono::steady_clock::now() + 5s;
  while (writer.matched_readers() == 0 && std::chrono::steady_clock::now() < end) {
    std::this_thread::sleep_for(10ms);
  }
  return writer.matched_readers() > 0;
}

/// Commands the reader delivers within `limit` (polling until `want` came).
std::vector<std::string> Collect(DebriefControlReader& reader, size_t want, std::chrono::milliseconds limit = 3000ms) {
  std::vector<std::string> got;
  const auto end = std::chrono::steady_clock::now() + limit;
  while (got.size() < want && std::chrono::steady_clock::now() < end) {
    reader.Poll(50ms, [&](const std::string& line) { got.push_back(line); });
  }
  return got;
}

TEST(DebriefControlTest, SignedCommandsArriveInOrder) {
  DdsParticipant participant(testing::TestDomainId());
  DebriefControlReader reader(participant, "deb", Key(7));
  DebriefControlWriter writer(participant, "deb", Key(7));
  ASSERT_TRUE(Matched(writer));
  for (const char* line : {"pause", "seek 1.500000", "next"}) ASSERT_TRUE(writer.Send(line));
  EXPECT_EQ(Collect(reader, 3), (std::vector<std::string>{"pause", "seek 1.500000", "next"}));
  EXPECT_EQ(reader.stats().accepted, 3u);
  EXPECT_FALSE(writer.Send(std::string(65, 'x'))) << "longer than the language allows";
}

TEST(DebriefControlTest, UnsignedForgedAndForeignCommandsAreRefused) {
  DdsParticipant participant(testing::TestDomainId());
  DebriefControlReader reader(participant, "deb", Key(7));
  DebriefControlWriter open(participant, "deb", std::nullopt);    // no key: unsigned
  DebriefControlWriter forger(participant, "deb", Key(9));        // another key
  DebriefControlWriter other(participant, "other", Key(7));       // another session
  ASSERT_TRUE(Matched(open) && Matched(forger) && Matched(other));
  ASSERT_TRUE(open.Send("pause"));
  ASSERT_TRUE(forger.Send("seek 3.000000"));
  ASSERT_TRUE(other.Send("play"));
  EXPECT_TRUE(Collect(reader, 1, 1000ms).empty());
  EXPECT_EQ(reader.stats().unsigned_samples, 1u);
  EXPECT_EQ(reader.stats().forged, 1u);
  EXPECT_EQ(reader.stats().accepted, 0u);
}

TEST(DebriefControlTest, AReplayedCommandIsRefused) {
  DdsParticipant participant(testing::TestDomainId());
  DebriefControlReader reader(participant, "deb", Key(7));
  DdsTopic topic(participant, EnvelopeKind::kControl);
  DdsWriter raw(topic);
  ASSERT_TRUE(raw.WaitForReaders(1, 5s));
  // One signed command, captured as sent, then sent again.
  PayloadAuthenticator signer(Key(7), std::string(ObserverStreamDomain(EnvelopeKind::kControl)), "deb");
  v1::DebriefControl msg;
  msg.set_command("seek 2.000000");
  msg.set_seq(1);
  msg.set_epoch(static_cast<uint64_t>(RealtimeNowNs()) - 1000);
  msg.set_wall_ns(RealtimeNowNs());
  Encoder encoder;
  const auto bytes = encoder.Encode(msg, nullptr, &signer);
  ASSERT_TRUE(bytes);
  const std::vector<uint8_t> captured(bytes->begin(), bytes->end());
  ASSERT_EQ(raw.Publish(EnvelopeKind::kControl, 1, "deb", captured), DdsPublishStatus::kOk);
  EXPECT_EQ(Collect(reader, 1), std::vector<std::string>{"seek 2.000000"});
  ASSERT_EQ(raw.Publish(EnvelopeKind::kControl, 2, "deb", captured), DdsPublishStatus::kOk);
  EXPECT_TRUE(Collect(reader, 1, 1000ms).empty());
  EXPECT_EQ(reader.stats().stale, 1u);
}

TEST(DebriefControlTest, AnOpenSessionTakesUnsignedCommandsButNotGarbage) {
  DdsParticipant participant(testing::TestDomainId());
  DebriefControlReader reader(participant, "deb", std::nullopt);
  DebriefControlWriter writer(participant, "deb", std::nullopt);
  DdsTopic topic(participant, EnvelopeKind::kControl);
  DdsWriter raw(topic);
  ASSERT_TRUE(raw.WaitForReaders(1, 5s) && Matched(writer));
  const std::vector<uint8_t> garbage = {0xff, 0xff, 0xff, 0x01};
  ASSERT_EQ(raw.Publish(EnvelopeKind::kControl, 9, "deb", garbage), DdsPublishStatus::kOk);
  ASSERT_TRUE(writer.Send("play"));
  EXPECT_EQ(Collect(reader, 1), std::vector<std::string>{"play"});
  EXPECT_EQ(reader.stats().malformed, 1u);
}

}  // namespace
}  // namespace cutsim::transport
