// The observers' mesh stream: snapshot/delta encoding, replica, hash, bad
// input, and the "no encoding without a reader" rule. DDS runs in-process on a
// per-process domain with the default (loopback) configuration.

#include "common/transport/mesh_stream.h"

#include <array>
#include <chrono>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "common/core/clock.h"
#include "common/mesh/generators.h"
#include "common/mesh/surface.h"
#include "common/transport/proto_vec.h"
#include "tests/support/fake_mesh.h"
#include "tests/unit/transport/test_util.h"

namespace cutsim::transport {
namespace {

using namespace std::chrono_literals;

using support::FakeMesh;

struct Sample {
  EnvelopeKind kind;
  uint64_t seq;
  std::vector<uint8_t> bytes;
};

/// A publisher plus raw readers that record every payload it sends.
class StreamHarness {
 public:
  explicit StreamHarness(MeshStreamOptions opts = {})
      : session_(testing::UniqueSession("ms")),
        participant_(testing::TestDomainId()),
        pub_(participant_, session_, opts),
        snap_topic_(participant_, EnvelopeKind::kSnapshot),
        delta_topic_(participant_, EnvelopeKind::kDelta),
        snap_reader_(snap_topic_, session_),
        delta_reader_(delta_topic_, session_),
        sub_(participant_, session_) {
    const auto deadline = MonotonicNs() + 5'000'000'000LL;
    while (!pub_.HasReaders() && MonotonicNs() < deadline) {
      snap_reader_.Take(10ms, [](const EnvelopeView&) {});
    }
  }

  /// Publishes `mesh` and returns what went on the wire for that frame.
  std::vector<Sample> Publish(const FakeMesh& mesh) {
    const MeshStreamStats before = pub_.stats();
    pub_.PublishFrame([&](MeshFrame& f) { mesh.Fill(f); });
    const MeshStreamStats after = pub_.stats();
    const size_t want = (after.snapshots - before.snapshots) + (after.deltas - before.deltas);
    std::vector<Sample> got;
    const auto deadline = MonotonicNs() + 5'000'000'000LL;
    auto keep = [&](const EnvelopeView& e) {
      got.push_back({e.kind, e.seq, {e.payload.begin(), e.payload.end()}});
    };
    while (got.size() < want && MonotonicNs() < deadline) {
      snap_reader_.Take(0ns, keep);
      delta_reader_.Take(got.size() < want ? 5ms : 0ms, keep);
    }
    EXPECT_EQ(got.size(), want);
    // Snapshot first, as published.
    std::stable_sort(got.begin(), got.end(),
                     [](const Sample& a, const Sample& b) { return a.kind < b.kind; });
    return got;
  }

  MeshStreamPublisher& pub() { return pub_; }
  DdsParticipant& participant() { return participant_; }
  const std::string& session() const { return session_; }
  MeshStreamSubscriber& sub() { return sub_; }

 private:
  std::string session_;
  DdsParticipant participant_;
  MeshStreamPublisher pub_;
  DdsTopic snap_topic_;
  DdsTopic delta_topic_;
  DdsReader snap_reader_;
  DdsReader delta_reader_;
  MeshStreamSubscriber sub_;  // fed by hand (Feed), never polled
};

/// A subscriber fed by hand (Process); its own readers are never polled.
void Feed(MeshStreamSubscriber& sub, const std::vector<Sample>& samples, const std::string& session) {
  for (const Sample& s : samples) sub.Process(s.kind, session, s.seq, s.bytes);
}

void ExpectReplicaEquals(const MeshReplica& r, const MeshStreamPublisher& pub, const FakeMesh& m) {
  ASSERT_TRUE(r.synced());
  EXPECT_EQ(r.hash(), pub.stats().last_hash);
  EXPECT_EQ(r.seq(), pub.stats().last_seq);
  EXPECT_EQ(r.hash(), r.ComputeHash());
  ASSERT_EQ(r.world_q().rows(), m.world.rows());
  EXPECT_TRUE(r.world_q() == pub.sent_world());
  EXPECT_TRUE(r.tets() == m.tets);
  EXPECT_TRUE(r.surface() == m.surface);
  EXPECT_EQ(r.opened(), m.opened);
  EXPECT_EQ(r.topology_version(), m.version);
  // The state as sent is within the move tolerance + half a quantum of the truth.
  const double q = pub.options().quantum_m;
  EXPECT_LE((r.world() - m.world).cwiseAbs().maxCoeff(), 1.5 * q + 1e-12);
  EXPECT_LE((r.Rest() - m.rest).cwiseAbs().maxCoeff(), 0.5 * q + 1e-12);
}

TEST(MeshStreamTest, QuantiseAndStressCodes) {
  EXPECT_EQ(Quantise(0.0123456, 1e-5), 1235);
  EXPECT_EQ(Quantise(-0.0123449, 1e-5), -1234);
  EXPECT_EQ(Quantise(1e9, 1e-5), kMaxQuantised);
  EXPECT_EQ(Quantise(std::nan(""), 1e-5), 0);
  for (const int32_t k : {0, 1, -1, 12345, -kMaxQuantised, kMaxQuantised}) {
    const auto f = static_cast<float>(1e-5 * k);
    EXPECT_EQ(Quantise(f, 1e-5), k);  // a float carries k·quantum exactly
  }
  EXPECT_EQ(StressCode(0.0), 0);
  for (const double s : {1.0, 1e3, -2.5e4, 7e6}) {
    EXPECT_NEAR(StressFromCode(StressCode(s)) / s, 1.0, 0.03);
  }
}

TEST(MeshStreamTest, HashSeesEveryPartOfTheState) {
  FakeMesh m(2);
  QuantisedPositions q(m.world.rows(), 3);
  for (Eigen::Index i = 0; i < q.size(); ++i) q.data()[i] = Quantise(m.world.data()[i], 1e-5);
  const uint64_t h = MeshHash(1, q, m.tets, m.surface, m.opened);
  EXPECT_EQ(h, MeshHash(1, q, m.tets, m.surface, {}));  // empty opened == all zero
  EXPECT_NE(h, MeshHash(2, q, m.tets, m.surface, m.opened));
  QuantisedPositions q2 = q;
  q2(3, 1) += 1;
  EXPECT_NE(h, MeshHash(1, q2, m.tets, m.surface, m.opened));
  mesh::Tets t2 = m.tets;
  std::swap(t2(0, 0), t2(0, 1));
  EXPECT_NE(h, MeshHash(1, q, t2, m.surface, m.opened));
  std::vector<uint8_t> o2 = m.opened;
  o2.back() = 1;
  EXPECT_NE(h, MeshHash(1, q, m.tets, m.surface, o2));
}

TEST(MeshStreamTest, NothingIsEncodedWithoutAReader) {
  DdsParticipant participant(testing::TestDomainId());
  const std::string session = testing::UniqueSession("ms");
  MeshStreamPublisher pub(participant, session);
  FakeMesh m(3);
  int fills = 0;
  for (int i = 0; i < 20; ++i) pub.PublishFrame([&](MeshFrame& f) { ++fills, m.Fill(f); });
  EXPECT_EQ(fills, 0);
  EXPECT_FALSE(pub.HasReaders());
  EXPECT_EQ(pub.stats().skipped_no_reader, 20U);
  EXPECT_EQ(pub.stats().snapshots + pub.stats().deltas, 0U);
  EXPECT_EQ(pub.stats().encode_ns, 0);

  MeshStreamSubscriber sub(participant, session);
  const auto deadline = MonotonicNs() + 5'000'000'000LL;
  while (!pub.HasReaders() && MonotonicNs() < deadline) sub.Poll(10ms);
  ASSERT_TRUE(pub.HasReaders());
  pub.PublishFrame([&](MeshFrame& f) { ++fills, m.Fill(f); });
  EXPECT_EQ(fills, 1);
  EXPECT_EQ(pub.stats().snapshots, 1U);
  while (!sub.replica().synced() && MonotonicNs() < deadline) sub.Poll(10ms);
  ExpectReplicaEquals(sub.replica(), pub, m);
}

TEST(MeshStreamTest, RandomDeformationsAndTopologyChangesKeepTheHash) {
  StreamHarness h({.keyframe_interval_s = 0});  // no keyframes: everything via deltas
  MeshStreamSubscriber& sub = h.sub();
  FakeMesh m(4);
  m.stress.assign(static_cast<size_t>(m.world.rows()), 0.0);
  std::mt19937 rng(12345);
  std::uniform_real_distribution<double> u(-1, 1);
  std::uniform_int_distribution<int> coin(0, 9);
  Feed(sub, h.Publish(m), h.session());
  ExpectReplicaEquals(sub.replica(), h.pub(), m);
  const uint64_t snapshots_after_join = h.pub().stats().snapshots;
  for (int frame = 1; frame <= 120; ++frame) {
    m.frame = static_cast<uint64_t>(frame);
    m.sim_time = 0.05 * frame;
    // Random motion: most nodes still, some tiny (below tolerance), some large.
    for (Eigen::Index i = 0; i < m.world.rows(); ++i) {
      const int c = coin(rng);
      if (c == 0) m.world.row(i) += 1e-3 * Eigen::RowVector3d(u(rng), u(rng), u(rng));
      if (c == 1) m.world.row(i) += 3e-6 * Eigen::RowVector3d(u(rng), u(rng), u(rng));
      if (c == 2) m.stress[static_cast<size_t>(i)] = 1e4 * std::abs(u(rng));
    }
    if (coin(rng) == 0) {  // topology: split a random node (adds a node, retargets tets)
      m.Split(std::uniform_int_distribution<int32_t>(0, static_cast<int32_t>(m.world.rows()) - 1)(rng));
    }
    if (coin(rng) == 1) {  // a cut moving a rest position (method paper §3.3)
      m.rest(coin(rng), 1) += 2e-4;
      ++m.version;
    }
    Feed(sub, h.Publish(m), h.session());
    ASSERT_NO_FATAL_FAILURE(ExpectReplicaEquals(sub.replica(), h.pub(), m)) << "frame " << frame;
    ASSERT_EQ(sub.replica().stress().size(), m.stress.size());
  }
  EXPECT_GT(m.version, 3U);
  EXPECT_EQ(h.pub().stats().snapshots, snapshots_after_join);  // only deltas after the first
  EXPECT_EQ(sub.stats().hash_mismatches, 0U);
  EXPECT_EQ(sub.stats().resyncs, 0U);
  EXPECT_EQ(sub.stats().deltas, 120U);
}

TEST(MeshStreamTest, DroppedDeltaIsAGapAndTheNextSnapshotResyncs) {
  StreamHarness h({.keyframe_interval_s = 0});
  MeshStreamSubscriber& sub = h.sub();
  FakeMesh m(3);
  Feed(sub, h.Publish(m), h.session());
  m.Poke({0.05, 0.05, 0.1}, 0.04, 0.002);
  Feed(sub, h.Publish(m), h.session());
  ASSERT_TRUE(sub.current());
  m.Poke({0.05, 0.05, 0.1}, 0.04, 0.004);
  (void)h.Publish(m);  // dropped
  m.Poke({0.05, 0.05, 0.1}, 0.04, 0.006);
  Feed(sub, h.Publish(m), h.session());
  EXPECT_FALSE(sub.replica().synced());
  EXPECT_EQ(sub.stats().gaps, 1U);
  EXPECT_EQ(sub.stats().resyncs, 1U);
  // More deltas while out of sync are held, not applied.
  m.Poke({0.05, 0.05, 0.1}, 0.04, 0.007);
  Feed(sub, h.Publish(m), h.session());
  EXPECT_FALSE(sub.replica().synced());
  // A new reader makes the publisher send a snapshot; we resync from it.
  MeshStreamSubscriber joiner(h.participant(), h.session());
  const auto deadline = MonotonicNs() + 5'000'000'000LL;
  std::vector<Sample> got;
  while (MonotonicNs() < deadline) {
    m.Poke({0.05, 0.05, 0.1}, 0.04, 0.008);
    got = h.Publish(m);
    if (got.front().kind == EnvelopeKind::kSnapshot) break;
  }
  ASSERT_EQ(got.front().kind, EnvelopeKind::kSnapshot);
  Feed(sub, got, h.session());
  ExpectReplicaEquals(sub.replica(), h.pub(), m);
  EXPECT_TRUE(sub.current());
  EXPECT_EQ(sub.stats().resyncs, 1U);
  EXPECT_EQ(sub.stats().hash_mismatches, 0U);
}

TEST(MeshStreamTest, CorruptedDeltaIsAHashMismatchThenResync) {
  StreamHarness h({.keyframe_interval_s = 0.3});
  MeshStreamSubscriber& sub = h.sub();
  FakeMesh m(3);
  Feed(sub, h.Publish(m), h.session());
  m.Poke({0.05, 0.05, 0.1}, 0.04, 0.002);
  std::vector<Sample> got = h.Publish(m);
  ASSERT_EQ(got.size(), 1U);
  v1::MeshDelta delta;
  ASSERT_TRUE(delta.ParseFromArray(got[0].bytes.data(), static_cast<int>(got[0].bytes.size())));
  ASSERT_GT(delta.moved_dq_size(), 0);
  delta.set_moved_dq(0, delta.moved_dq(0) + 1);  // one quantum off: well-formed, wrong
  std::string bytes = delta.SerializeAsString();
  sub.Process(EnvelopeKind::kDelta, h.session(), delta.seq(),
              {reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size()});
  EXPECT_EQ(sub.stats().hash_mismatches, 1U);
  EXPECT_EQ(sub.stats().resyncs, 1U);
  EXPECT_FALSE(sub.replica().synced());
  EXPECT_FALSE(sub.current());
  // Keep streaming until the keyframe arrives: then in sync again.
  const auto deadline = MonotonicNs() + 5'000'000'000LL;
  while (!sub.replica().synced() && MonotonicNs() < deadline) {
    m.Poke({0.05, 0.05, 0.1}, 0.04, 0.002 + 1e-3 * std::sin(1e-9 * static_cast<double>(MonotonicNs())));
    Feed(sub, h.Publish(m), h.session());
    std::this_thread::sleep_for(20ms);  // let the keyframe interval pass (a test, not a DDS wait)
  }
  ExpectReplicaEquals(sub.replica(), h.pub(), m);
  EXPECT_EQ(sub.stats().hash_mismatches, 1U);
}

TEST(MeshStreamTest, BadSamplesAreCountedAndIgnored) {
  StreamHarness h({.keyframe_interval_s = 0});
  MeshStreamSubscriber& sub = h.sub();
  FakeMesh m(3);
  Feed(sub, h.Publish(m), h.session());
  m.Poke({0.05, 0.05, 0.1}, 0.04, 0.002);
  const std::vector<Sample> next = h.Publish(m);
  ASSERT_EQ(next.size(), 1U);
  const uint64_t hash_before = sub.replica().hash();
  const auto send = [&](EnvelopeKind kind, const std::string& session, uint64_t seq,
                        const std::string& bytes) {
    sub.Process(kind, session, seq, {reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size()});
  };
  // Garbage, oversized, foreign session (envelope key and payload).
  send(EnvelopeKind::kDelta, h.session(), next[0].seq, std::string("\xff\xff\xff\xff\x0f garbage", 13));
  send(EnvelopeKind::kSnapshot, h.session(), 1, std::string("\x0a\x80\x80\x80\x80\x10", 6));
  send(EnvelopeKind::kStatus, h.session(), 1, std::string(MaxPayloadBytes<v1::SessionStatus>() + 1, '\0'));
  send(EnvelopeKind::kDelta, "someone_else", next[0].seq, std::string(next[0].bytes.begin(), next[0].bytes.end()));
  v1::MeshDelta d;
  ASSERT_TRUE(d.ParseFromArray(next[0].bytes.data(), static_cast<int>(next[0].bytes.size())));
  {
    v1::MeshDelta foreign = d;
    foreign.set_session("someone_else");
    send(EnvelopeKind::kDelta, h.session(), d.seq(), foreign.SerializeAsString());
  }
  // Well-formed protobuf, inconsistent content.
  {
    v1::MeshDelta bad = d;
    bad.add_moved_nodes(1'000'000);  // out of range
    bad.add_moved_dq(1), bad.add_moved_dq(1), bad.add_moved_dq(1);
    send(EnvelopeKind::kDelta, h.session(), d.seq(), bad.SerializeAsString());
    bad = d;
    bad.add_changed_tets(0);
    send(EnvelopeKind::kDelta, h.session(), d.seq(), bad.SerializeAsString());  // no rows
    bad = d;
    bad.set_num_nodes(1u << 31);
    send(EnvelopeKind::kDelta, h.session(), d.seq(), bad.SerializeAsString());
    bad = d;
    bad.set_quantum(1e-3);
    send(EnvelopeKind::kDelta, h.session(), d.seq(), bad.SerializeAsString());
    bad = d;
    if (bad.moved_dq_size() > 0) bad.set_moved_dq(0, 1 << 30);  // leaves the quantised range
    send(EnvelopeKind::kDelta, h.session(), d.seq(), bad.SerializeAsString());
    bad = d;
    send(EnvelopeKind::kDelta, h.session(), d.seq() + 7, bad.SerializeAsString());  // envelope ≠ payload seq
    v1::MeshSnapshot snap;
    snap.set_session(h.session());
    snap.set_seq(d.seq() + 5);
    snap.set_epoch(d.epoch());  // the genuine server's epoch: it reaches the replica's checks
    snap.set_wall_ns(d.wall_ns());
    snap.set_quantum(1e-5);
    snap.add_world(0), snap.add_world(0), snap.add_world(0);
    snap.add_rest(0), snap.add_rest(0), snap.add_rest(0);
    snap.add_tets(0), snap.add_tets(0), snap.add_tets(0), snap.add_tets(9);  // index out of range
    send(EnvelopeKind::kSnapshot, h.session(), snap.seq(), snap.SerializeAsString());
  }
  {
    v1::MeshDelta unknown = d;
    unknown.set_base_topology_version(99);
    send(EnvelopeKind::kDelta, h.session(), d.seq(), unknown.SerializeAsString());
  }
  EXPECT_TRUE(sub.replica().synced());
  EXPECT_EQ(sub.replica().hash(), hash_before);  // nothing changed the state
  EXPECT_EQ(sub.stats().malformed, 9U);
  EXPECT_EQ(sub.stats().oversized, 1U);
  EXPECT_EQ(sub.stats().foreign_session, 2U);
  EXPECT_EQ(sub.stats().unknown_topology, 1U);
  EXPECT_EQ(sub.stats().hash_mismatches, 0U);
  EXPECT_EQ(sub.stats().resyncs, 0U);
  // The genuine delta still applies.
  Feed(sub, next, h.session());
  ExpectReplicaEquals(sub.replica(), h.pub(), m);
}

TEST(MeshStreamTest, DeltaForALocalPokeIsAtMostTenPercentOfASnapshot) {
  // A ~20k-tet box (16³ cells × 6 = 24 576 tets, 4 913 nodes), 10 cm.
  StreamHarness h({.keyframe_interval_s = 0});
  FakeMesh m(16);
  (void)h.Publish(m);
  const uint64_t snapshot_bytes = h.pub().stats().last_snapshot_bytes;
  m.Poke({0.05, 0.05, 0.1}, 0.02, 0.003);  // a 2 cm wide, 3 mm deep poke on the top
  (void)h.Publish(m);
  const uint64_t poke_bytes = h.pub().stats().last_delta_bytes;
  m.Cut(0.05, 0.05);  // a plane cut half-way down
  (void)h.Publish(m);
  const uint64_t cut_bytes = h.pub().stats().last_delta_bytes;
  m.frame += 1;
  (void)h.Publish(m);
  const uint64_t still_bytes = h.pub().stats().last_delta_bytes;
  EXPECT_LE(10 * poke_bytes, snapshot_bytes);
  EXPECT_LT(cut_bytes, snapshot_bytes);
  EXPECT_LT(still_bytes, 96U);  // the header: session, seq, frame, hash, epoch, signing time
}

SessionKey TestKey(char fill = 'c') { return ParseSessionKey(std::string(64, fill), "test"); }

/// Serialises `msg` and appends the trailer `key` gives it for `kind`.
std::vector<uint8_t> SignedAs(const google::protobuf::MessageLite& msg, const SessionKey& key,
                              EnvelopeKind kind, const std::string& session) {
  PayloadAuthenticator signer(key, std::string(ObserverStreamDomain(kind)), session);
  const std::string body = msg.SerializeAsString();
  std::vector<uint8_t> out(body.begin(), body.end());
  std::array<uint8_t, kTrailerBytes> trailer{};
  EXPECT_TRUE(signer.MakeTrailer(out, trailer));
  out.insert(out.end(), trailer.begin(), trailer.end());
  return out;
}

TEST(MeshStreamAuth, OnlyFramesSignedWithTheKeyReachTheReplica) {
  StreamHarness h({.keyframe_interval_s = 0, .key = TestKey()});
  FakeMesh m(3);
  const std::vector<Sample> first = h.Publish(m);
  MeshStreamSubscriber keyed(h.participant(), h.session(), TestKey());
  MeshStreamSubscriber wrong(h.participant(), h.session(), TestKey('d'));
  MeshStreamSubscriber open(h.participant(), h.session());
  Feed(keyed, first, h.session());
  Feed(wrong, first, h.session());
  Feed(open, first, h.session());
  ExpectReplicaEquals(keyed.replica(), h.pub(), m);
  EXPECT_TRUE(keyed.stats().authenticated);
  EXPECT_FALSE(wrong.replica().synced());
  EXPECT_EQ(wrong.stats().forged, first.size());
  ExpectReplicaEquals(open.replica(), h.pub(), m);  // the trailer is a field an open viewer skips
  EXPECT_FALSE(open.stats().authenticated);

  // The next frame without its trailer is unsigned: refused, and the signed
  // one still applies after it.
  m.Poke({0.05, 0.05, 0.1}, 0.04, 0.002);
  const std::vector<Sample> next = h.Publish(m);
  ASSERT_FALSE(next.empty());
  const uint64_t hash_before = keyed.replica().hash();
  for (const Sample& s : next) {
    ASSERT_GT(s.bytes.size(), kTrailerBytes);
    const std::vector<uint8_t> stripped(s.bytes.begin(), s.bytes.end() - kTrailerBytes);
    keyed.Process(s.kind, h.session(), s.seq, stripped);
  }
  EXPECT_EQ(keyed.stats().unsigned_samples, next.size());
  EXPECT_EQ(keyed.replica().hash(), hash_before);
  Feed(keyed, next, h.session());
  ExpectReplicaEquals(keyed.replica(), h.pub(), m);
}

TEST(MeshStreamAuth, AForgedHighSequenceNeverTakesTheViewerOver) {
  StreamHarness h({.keyframe_interval_s = 0, .key = TestKey()});
  FakeMesh m(3);
  const std::vector<Sample> first = h.Publish(m);
  MeshStreamSubscriber keyed(h.participant(), h.session(), TestKey());
  Feed(keyed, first, h.session());
  ASSERT_TRUE(keyed.replica().synced());
  const uint64_t hash_before = keyed.replica().hash();

  // A snapshot of another mesh with a huge sequence number, signed with a
  // key that is not the session's, and the same unsigned.
  v1::MeshSnapshot forged;
  ASSERT_EQ(first[0].kind, EnvelopeKind::kSnapshot);
  ASSERT_TRUE(forged.ParseFromArray(first[0].bytes.data(),
                                    static_cast<int>(first[0].bytes.size() - kTrailerBytes)));
  const uint64_t huge = uint64_t{1} << 62;
  forged.set_seq(huge);
  for (int i = 0; i < forged.world_size(); ++i) forged.set_world(i, forged.world(i) + 0.01F);
  keyed.Process(EnvelopeKind::kSnapshot, h.session(), huge,
                SignedAs(forged, TestKey('e'), EnvelopeKind::kSnapshot, h.session()));
  const std::string plain = forged.SerializeAsString();
  keyed.Process(EnvelopeKind::kSnapshot, h.session(), huge,
                {reinterpret_cast<const uint8_t*>(plain.data()), plain.size()});
  EXPECT_EQ(keyed.stats().forged, 1U);
  EXPECT_EQ(keyed.stats().unsigned_samples, 1U);
  EXPECT_EQ(keyed.replica().hash(), hash_before);

  // A 46-byte delta that claims 2^26 nodes, correctly signed (a buggy or
  // hostile key holder): refused before anything is allocated.
  v1::MeshDelta claim;
  claim.set_session(h.session());
  claim.set_seq(keyed.replica().seq() + 1);
  claim.set_quantum(h.pub().options().quantum_m);
  claim.set_num_nodes(uint32_t{1} << 26);
  claim.set_num_tets(static_cast<uint32_t>(keyed.replica().tets().rows()));
  claim.set_base_topology_version(keyed.replica().topology_version());
  claim.set_topology_version(keyed.replica().topology_version());
  claim.set_epoch(h.pub().epoch());
  claim.set_wall_ns(RealtimeNowNs());
  const Eigen::Index rows_before = keyed.replica().world_q().rows();
  keyed.Process(EnvelopeKind::kDelta, h.session(), claim.seq(),
                SignedAs(claim, TestKey(), EnvelopeKind::kDelta, h.session()));
  EXPECT_EQ(keyed.stats().malformed, 1U);
  EXPECT_EQ(keyed.replica().world_q().rows(), rows_before);

  // The genuine stream goes on: the refused samples used up no sequence number.
  m.Poke({0.05, 0.05, 0.1}, 0.04, 0.002);
  Feed(keyed, h.Publish(m), h.session());
  ExpectReplicaEquals(keyed.replica(), h.pub(), m);
}

TEST(MeshStreamAuth, TheViewerFollowsOneServerAndARestartedServerTakesOver) {
  StreamHarness h({.keyframe_interval_s = 0, .key = TestKey()});
  FakeMesh m(3);
  const std::vector<Sample> first = h.Publish(m);
  MeshStreamSubscriber keyed(h.participant(), h.session(), TestKey());
  Feed(keyed, first, h.session());
  ASSERT_TRUE(keyed.replica().synced());

  // A restarted server: a newer epoch, its sequence numbers lower, another mesh.
  v1::MeshSnapshot restarted;
  ASSERT_TRUE(restarted.ParseFromArray(first[0].bytes.data(),
                                       static_cast<int>(first[0].bytes.size() - kTrailerBytes)));
  const int64_t now = RealtimeNowNs();
  ASSERT_GT(static_cast<uint64_t>(now), h.pub().epoch());
  restarted.set_epoch(static_cast<uint64_t>(now));
  restarted.set_wall_ns(now);
  restarted.set_seq(3);
  keyed.Process(EnvelopeKind::kSnapshot, h.session(), 3,
                SignedAs(restarted, TestKey(), EnvelopeKind::kSnapshot, h.session()));
  EXPECT_EQ(keyed.stats().server_changes, 1U);
  ASSERT_TRUE(keyed.replica().synced());
  EXPECT_EQ(keyed.replica().seq(), 3U);

  // The old server, still publishing, is now the older epoch: refused while
  // the followed one is alive, whatever its sequence numbers.
  m.Poke({0.05, 0.05, 0.1}, 0.04, 0.002);
  const std::vector<Sample> old_server = h.Publish(m);
  Feed(keyed, old_server, h.session());
  EXPECT_EQ(keyed.stats().other_server, old_server.size());
  EXPECT_EQ(keyed.replica().seq(), 3U);
}

TEST(MeshStreamTest, LateJoinerStartsFromTheCurrentMesh) {
  DdsParticipant participant(testing::TestDomainId());
  const std::string session = testing::UniqueSession("ms");
  MeshStreamPublisher pub(participant, session, {.keyframe_interval_s = 60});
  FakeMesh m(6);
  MeshStreamSubscriber first(participant, session);
  auto step = [&](int i) {
    m.frame = static_cast<uint64_t>(i);
    m.Poke({0.05, 0.05, 0.1}, 0.04, 0.001 * (i % 7));
    pub.PublishFrame([&](MeshFrame& f) { m.Fill(f); });
  };
  int i = 0;
  const auto deadline = MonotonicNs() + 5'000'000'000LL;
  while (!first.current() && MonotonicNs() < deadline) {
    step(++i);
    first.Poll(20ms);
  }
  ASSERT_TRUE(first.current());
  for (int k = 0; k < 20; ++k) step(++i);  // the retained keyframe is now 20 frames old
  const int64_t join_ns = MonotonicNs();
  MeshStreamSubscriber late(participant, session);
  int64_t current_ns = 0;
  while (MonotonicNs() < deadline + 5'000'000'000LL) {
    step(++i);
    first.Poll(0ns);
    late.Poll(20ms);
    if (late.current()) {
      current_ns = MonotonicNs();
      break;
    }
  }
  ASSERT_TRUE(late.current());
  // Current = the publisher's latest frame, not the old keyframe.
  EXPECT_EQ(late.replica().seq(), pub.stats().last_seq);
  EXPECT_EQ(late.replica().hash(), pub.stats().last_hash);
  EXPECT_EQ(late.stats().resyncs, 0U);
  EXPECT_LT(current_ns - join_ns, 2'000'000'000LL);
}

// Encoding (diff, encode, write) happens only while a reader listens; with
// readers every frame after the joining snapshot is a delta. The cost per
// frame is measured by bench/mesh_stream_bench.cc.
TEST(MeshStreamTest, EncodesOnlyForReadersWithZeroOneAndFourReaders) {
  FakeMesh m(16);  // 24 576 tets
  DdsParticipant participant(testing::TestDomainId());
  for (const int readers : {0, 1, 4}) {
    const std::string session = testing::UniqueSession("ms");
    MeshStreamPublisher pub(participant, session, {.keyframe_interval_s = 0});
    std::vector<std::unique_ptr<MeshStreamSubscriber>> subs;
    for (int r = 0; r < readers; ++r) {
      subs.push_back(std::make_unique<MeshStreamSubscriber>(participant, session));
    }
    const auto deadline = MonotonicNs() + 5'000'000'000LL;
    while (readers > 0 && !pub.HasReaders() && MonotonicNs() < deadline) {
      subs[0]->Poll(10ms);
    }
    constexpr int kFrames = 30;
    for (int i = 0; i < kFrames + 1; ++i) {
      m.Poke({0.05, 0.05, 0.1}, 0.03, 0.0001 * i);
      pub.PublishFrame([&](MeshFrame& f) { m.Fill(f); });
      for (auto& s : subs) s->Poll(0ns);
    }
    if (readers == 0) {
      EXPECT_EQ(pub.stats().encode_ns, 0);
      EXPECT_EQ(pub.stats().skipped_no_reader, static_cast<uint64_t>(kFrames + 1));
    } else {
      EXPECT_EQ(pub.stats().deltas, static_cast<uint64_t>(kFrames));
    }
  }
}

v1::ObserverSession ObservedAt(int i) {
  v1::ObserverSession o;
  o.set_sim_time(0.01 * i);
  o.set_wall_time(0.011 * i);
  o.set_cuts(static_cast<uint64_t>(i / 3));
  o.set_topology_version(1);
  v1::ToolView* t = o.add_tools();
  SetVec3(Eigen::Vector3d(0.001 * i, 0.02, 0.03), t->mutable_tip());
  SetVec3(Eigen::Vector3d(0, 0, 1), t->mutable_blade_dir());
  t->set_blade_length(0.02);
  SetVec3(Eigen::Vector3d(0, -0.1 * i, 0.5), t->mutable_force());
  t->set_contact(i % 2 == 0);
  return o;
}

// Every snapshot and delta carries the session as of its frame, so a viewer
// holds the tool and the clock of the mesh it shows, and one that starts
// from a snapshot alone has them at once.
TEST(MeshStreamTest, ObservedSessionTravelsWithSnapshotsAndDeltas) {
  StreamHarness h({.keyframe_interval_s = 1e-9});  // a snapshot every frame
  FakeMesh m(4);
  MeshStreamSubscriber late(h.participant(), h.session());
  EXPECT_FALSE(h.sub().observed().has_value());
  for (int i = 1; i <= 6; ++i) {
    m.frame = static_cast<uint64_t>(i);
    m.Poke({0.05, 0.05, 0.1}, 0.04, 0.001 * i);
    h.pub().SetObserved(ObservedAt(i));
    const std::vector<Sample> samples = h.Publish(m);
    Feed(h.sub(), samples, h.session());
    ASSERT_TRUE(h.sub().observed().has_value()) << "frame " << i;
    EXPECT_EQ(h.sub().observed()->SerializeAsString(), ObservedAt(i).SerializeAsString()) << "frame " << i;
    if (i == 5) {
      // A viewer that joins now: the snapshot alone brings the session.
      for (const Sample& s : samples) {
        if (s.kind == EnvelopeKind::kSnapshot) late.Process(s.kind, h.session(), s.seq, s.bytes);
      }
      ASSERT_TRUE(late.observed().has_value());
      EXPECT_DOUBLE_EQ(late.observed()->sim_time(), 0.05);
      EXPECT_DOUBLE_EQ(late.observed()->tools(0).tip().x(), 0.005);
    }
  }
}

// A session view a viewer cannot draw (too many tools, non-finite values, an
// absurd blade) is refused and counted; the mesh it came with still applies
// and the previous view stays. Measures that no session can have (infinite,
// negative) are refused the same way.
TEST(MeshStreamTest, ObservedSessionThatCannotBeDrawnIsRefused) {
  StreamHarness h;
  FakeMesh m(4);
  h.pub().SetObserved(ObservedAt(1));
  Feed(h.sub(), h.Publish(m), h.session());
  ASSERT_TRUE(h.sub().observed().has_value());
  std::vector<v1::ObserverSession> bad(5, ObservedAt(2));
  for (int k = 0; k < 4; ++k) *bad[0].add_tools() = bad[0].tools(0);  // five tools
  bad[1].mutable_tools(0)->mutable_tip()->set_y(std::numeric_limits<double>::quiet_NaN());
  bad[2].mutable_tools(0)->set_blade_length(1e9);
  bad[3].mutable_metrics()->set_peak_force(std::numeric_limits<double>::infinity());
  bad[4].mutable_metrics()->set_path_length(-1.0);
  uint64_t deltas = h.sub().stats().deltas;
  for (size_t k = 0; k < bad.size(); ++k) {
    m.frame = 2 + k;
    m.Poke({0.05, 0.05, 0.1}, 0.04, 0.001 * static_cast<double>(k + 1));
    h.pub().SetObserved(bad[k]);
    Feed(h.sub(), h.Publish(m), h.session());
    EXPECT_EQ(h.sub().stats().deltas, ++deltas) << "case " << k;
    EXPECT_EQ(h.sub().stats().malformed_observed, k + 1);
    EXPECT_DOUBLE_EQ(h.sub().observed()->sim_time(), 0.01) << "case " << k;
  }
  EXPECT_TRUE(h.sub().current() || h.sub().replica().synced());
}

}  // namespace
}  // namespace cutsim::transport
