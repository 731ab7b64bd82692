// DDS tests run on a per-process domain with the default (loopback)
// configuration, so parallel test processes never hear each other and no
// packet leaves 127.0.0.1.

#include "common/transport/dds.h"

#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <string>
#include <vector>

#include <google/protobuf/util/message_differencer.h>
#include <gtest/gtest.h>

#include "common/core/error.h"
#include "common/transport/codec.h"
#include "cutsim/v1/wire.pb.h"
#include "tests/unit/transport/test_util.h"

extern char** environ;

namespace cutsim::transport {
namespace {

using google::protobuf::util::MessageDifferencer;
using namespace std::chrono_literals;

struct Received {
  uint64_t seq;
  std::string session;
  std::vector<uint8_t> payload;
};

/// Takes from `reader` until `want` envelopes arrived or `timeout` passed.
std::vector<Received> TakeUntil(DdsReader& reader, size_t want, std::chrono::milliseconds timeout) {
  std::vector<Received> got;
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (got.size() < want && std::chrono::steady_clock::now() < deadline) {
    reader.Take(50ms, [&](const EnvelopeView& e) {
      got.push_back({e.seq, std::string(e.session), {e.payload.begin(), e.payload.end()}});
    });
  }
  return got;
}

v1::MeshSnapshot Snapshot(const std::string& session, uint64_t seq) {
  v1::MeshSnapshot s;
  s.set_session(session);
  s.set_seq(seq);
  s.set_topology_version(seq);
  for (int i = 0; i < 9; ++i) s.add_rest(0.1F * static_cast<float>(i));
  for (int i = 0; i < 4; ++i) s.add_tets(static_cast<uint32_t>(i));
  s.set_hash(0xABCDEF00ULL + seq);
  return s;
}

TEST(DdsTest, TopicNamesAndQosLiveInOneTable) {
  EXPECT_EQ(TopicSpecFor(EnvelopeKind::kSnapshot).name, "cutsim_snapshot");
  EXPECT_EQ(TopicSpecFor(EnvelopeKind::kDelta).name, "cutsim_delta");
  EXPECT_EQ(TopicSpecFor(EnvelopeKind::kStatus).name, "cutsim_status");
  const TopicSpec& snap = TopicSpecFor(EnvelopeKind::kSnapshot);
  EXPECT_TRUE(snap.reliable);
  EXPECT_TRUE(snap.transient_local);
  EXPECT_EQ(snap.history_depth, 1);
  const TopicSpec& delta = TopicSpecFor(EnvelopeKind::kDelta);
  EXPECT_TRUE(delta.reliable);
  EXPECT_FALSE(delta.transient_local);
  EXPECT_GT(delta.history_depth, 1);
}

TEST(DdsTest, DefaultConfigIsLoopbackUnlessTheUserNamesOne) {
  const char* saved = std::getenv("CYCLONEDDS_URI");
  const std::string saved_value = saved != nullptr ? saved : "";
  unsetenv("CYCLONEDDS_URI");
  const std::string def = ResolveDdsConfig();
  EXPECT_EQ(def, std::string(LoopbackDdsConfig()));
  EXPECT_NE(def.find("<NetworkInterface name=\"lo\""), std::string::npos);
  EXPECT_NE(def.find("<AllowMulticast>false</AllowMulticast>"), std::string::npos);
  EXPECT_NE(def.find("<Peer Address=\"127.0.0.1\"/>"), std::string::npos);
  setenv("CYCLONEDDS_URI", "file:///etc/user-cyclone.xml", 1);
  EXPECT_EQ(ResolveDdsConfig(), "file:///etc/user-cyclone.xml");
  EXPECT_EQ(ResolveDdsConfig("<CycloneDDS/>"), "<CycloneDDS/>");  // explicit beats env
  if (saved != nullptr) {
    setenv("CYCLONEDDS_URI", saved_value.c_str(), 1);
  } else {
    unsetenv("CYCLONEDDS_URI");
  }
}

TEST(DdsTest, InvalidDomainAndConfigThrowInputErrors) {
  try {
    DdsParticipant p(kMaxDdsDomainId + 1);
    FAIL() << "no throw";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source().field, "--dds-domain");
  }
  try {
    DdsParticipant p(testing::TestDomainId() + 10,
                     "<CycloneDDS><Domain Id=\"any\"><NoSuchElement/></Domain></CycloneDDS>");
    FAIL() << "no throw";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source().field, "--dds-config");
  }
}

TEST(DdsTest, EnvelopeRoundTripsThroughCyclone) {
  const std::string session = testing::UniqueSession("dds");
  DdsParticipant pub_side(testing::TestDomainId());
  DdsParticipant sub_side(testing::TestDomainId());  // same process: shares the domain
  DdsTopic pub_topic(pub_side, EnvelopeKind::kDelta);
  DdsTopic sub_topic(sub_side, EnvelopeKind::kDelta);
  DdsWriter writer(pub_topic);
  EXPECT_EQ(writer.matched_readers(), 0U);
  DdsReader reader(sub_topic, session);
  ASSERT_TRUE(writer.WaitForReaders(1, 5s));
  EXPECT_EQ(writer.match().total, 1U);

  v1::MeshDelta delta;
  delta.set_session(session);
  delta.set_seq(7);
  delta.add_moved_nodes(3);
  delta.add_moved_dq(-2);
  delta.set_hash(99);
  Encoder encoder;
  const auto bytes = encoder.Encode(delta);
  ASSERT_TRUE(bytes.has_value());
  ASSERT_EQ(writer.Publish(EnvelopeKind::kDelta, 7, session, *bytes), DdsPublishStatus::kOk);

  const auto got = TakeUntil(reader, 1, 5s);
  ASSERT_EQ(got.size(), 1U);
  EXPECT_EQ(got[0].seq, 7U);
  EXPECT_EQ(got[0].session, session);
  DecodeError err;
  const auto back = Decode<v1::MeshDelta>(got[0].payload, "cutsim_delta", &err);
  ASSERT_TRUE(back.has_value()) << err.Message();
  EXPECT_TRUE(MessageDifferencer::Equals(*back, delta));
  EXPECT_EQ(reader.stats().delivered, 1U);
}

TEST(DdsTest, LateJoinerGetsOnlyTheLastSnapshot) {
  const std::string session = testing::UniqueSession("dds");
  DdsParticipant participant(testing::TestDomainId());
  DdsTopic topic(participant, EnvelopeKind::kSnapshot);
  DdsWriter writer(topic);
  Encoder encoder;
  for (uint64_t seq = 1; seq <= 3; ++seq) {
    const auto bytes = encoder.Encode(Snapshot(session, seq));
    ASSERT_TRUE(bytes.has_value());
    ASSERT_EQ(writer.Publish(EnvelopeKind::kSnapshot, seq, session, *bytes), DdsPublishStatus::kOk);
  }
  // The reader is created after every write: TRANSIENT_LOCAL replays the
  // last sample per session (KEEP_LAST 1), nothing older.
  DdsReader reader(topic, session);
  const auto got = TakeUntil(reader, 1, 5s);
  ASSERT_EQ(got.size(), 1U);
  EXPECT_EQ(got[0].seq, 3U);
  const auto snap = Decode<v1::MeshSnapshot>(got[0].payload, "cutsim_snapshot");
  ASSERT_TRUE(snap.has_value());
  EXPECT_TRUE(MessageDifferencer::Equals(*snap, Snapshot(session, 3)));
  EXPECT_TRUE(TakeUntil(reader, 1, 200ms).empty());
}

TEST(DdsTest, ForeignSessionsAreIgnoredAndCounted) {
  const std::string mine = testing::UniqueSession("dds");
  const std::string other = testing::UniqueSession("dds");
  DdsParticipant participant(testing::TestDomainId());
  DdsTopic topic(participant, EnvelopeKind::kDelta);
  DdsWriter writer(topic);
  DdsReader reader(topic, mine);
  ASSERT_TRUE(writer.WaitForReaders(1, 5s));
  const std::vector<uint8_t> payload = {0x08, 0x01};
  ASSERT_EQ(writer.Publish(EnvelopeKind::kDelta, 1, other, payload), DdsPublishStatus::kOk);
  ASSERT_EQ(writer.Publish(EnvelopeKind::kDelta, 2, mine, payload), DdsPublishStatus::kOk);
  const auto got = TakeUntil(reader, 1, 5s);
  ASSERT_EQ(got.size(), 1U);
  EXPECT_EQ(got[0].seq, 2U);
  EXPECT_EQ(reader.stats().foreign_session, 1U);
}

TEST(DdsTest, WriterRefusesWrongKindBadSessionAndOversize) {
  DdsParticipant participant(testing::TestDomainId());
  DdsTopic topic(participant, EnvelopeKind::kStatus);
  DdsWriter writer(topic);
  const std::vector<uint8_t> payload = {0x08, 0x01};
  EXPECT_EQ(writer.Publish(EnvelopeKind::kDelta, 1, "s", payload), DdsPublishStatus::kWrongKind);
  EXPECT_EQ(writer.Publish(EnvelopeKind::kStatus, 1, "bad session", payload),
            DdsPublishStatus::kBadSession);
  const std::vector<uint8_t> big(MaxPayloadBytes<v1::SessionStatus>() + 1, 0);
  EXPECT_EQ(writer.Publish(EnvelopeKind::kStatus, 1, "s", big), DdsPublishStatus::kTooLarge);
  EXPECT_EQ(writer.failed(), 3U);
  EXPECT_EQ(writer.published(), 0U);
}

TEST(DdsTest, MatchedReadersFollowReadersComingAndGoing) {
  const std::string session = testing::UniqueSession("dds");
  DdsParticipant participant(testing::TestDomainId());
  DdsTopic topic(participant, EnvelopeKind::kSnapshot);
  DdsWriter writer(topic);
  EXPECT_EQ(writer.matched_readers(), 0U);
  EXPECT_FALSE(writer.WaitForReaders(1, 50ms));
  {
    DdsReader reader(topic, session);
    ASSERT_TRUE(writer.WaitForReaders(1, 5s));
    EXPECT_EQ(reader.matched_writers(), 1U);
  }
  const auto deadline = std::chrono::steady_clock::now() + 5s;
  while (writer.matched_readers() != 0 && std::chrono::steady_clock::now() < deadline) {
    writer.WaitForReaders(1000, 20ms);  // bounded WaitSet wait for the next match change
  }
  EXPECT_EQ(writer.matched_readers(), 0U);
  EXPECT_EQ(writer.match().total, 1U);
}

TEST(DdsTest, DiscoveryOverLoopbackReachesAnotherProcess) {
  // A separate process publishes a snapshot before we exist; unicast
  // discovery over 127.0.0.1 must match us and replay it (late joiner).
  const std::string session = testing::UniqueSession("peer");
  const std::string domain = std::to_string(testing::TestDomainId());
  const std::string seq = "4242";
  const char* path = CUTSIM_DDS_PEER;
  std::vector<char*> argv = {const_cast<char*>(path), const_cast<char*>(domain.c_str()),
                             const_cast<char*>(session.c_str()), const_cast<char*>(seq.c_str()),
                             nullptr};
  pid_t child = 0;
  ASSERT_EQ(posix_spawn(&child, path, nullptr, nullptr, argv.data(), environ), 0);

  std::vector<Received> got;
  {
    DdsParticipant participant(testing::TestDomainId());
    DdsTopic topic(participant, EnvelopeKind::kSnapshot);
    DdsReader reader(topic, session);
    got = TakeUntil(reader, 1, 12s);
    EXPECT_EQ(got.size(), 1U) << "matched writers " << reader.matched_writers() << ", foreign "
                              << reader.stats().foreign_session << ", no data "
                              << reader.stats().no_data << ", errors " << reader.stats().errors;
  }  // Deleting the reader tells the peer it may exit.
  int status = 0;
  pid_t done = 0;
  const auto deadline = std::chrono::steady_clock::now() + 12s;
  while ((done = waitpid(child, &status, WNOHANG)) == 0 && std::chrono::steady_clock::now() < deadline) {
    usleep(10'000);  // polling a child process, not a DDS entity
  }
  if (done == 0) {
    kill(child, SIGKILL);
    waitpid(child, &status, 0);
    ADD_FAILURE() << "peer process did not finish";
  } else {
    EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0)
        << "peer exited " << (WIFEXITED(status) ? WEXITSTATUS(status) : -1) << ", signal "
        << (WIFSIGNALED(status) ? WTERMSIG(status) : 0);
  }
  ASSERT_EQ(got.size(), 1U);
  EXPECT_EQ(got[0].seq, 4242U);
  const auto snap = Decode<v1::MeshSnapshot>(got[0].payload, "cutsim_snapshot");
  ASSERT_TRUE(snap.has_value());
  EXPECT_EQ(snap->session(), session);
  EXPECT_EQ(snap->world_size(), 12);
}

}  // namespace
}  // namespace cutsim::transport
