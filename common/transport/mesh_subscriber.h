#pragma once
/// @file
/// The viewer's end of the observer mesh stream: DDS readers of one
/// session's snapshot, delta and status topics feeding a `MeshReplica`, with
/// the bookkeeping that decides when the replica is current.

#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "common/transport/dds.h"
#include "common/transport/mesh_replica.h"
#include "common/transport/stream_auth.h"
#include "cutsim/v1/wire.pb.h"

namespace cutsim::transport {

struct MeshStreamSubscriberStats {
  uint64_t snapshots = 0;          ///< Snapshots applied.
  uint64_t deltas = 0;             ///< Deltas applied.
  uint64_t hash_checks = 0;        ///< Hashes verified (= snapshots + deltas applied).
  uint64_t hash_mismatches = 0;    ///< Snapshots or deltas whose hash disagreed.
  uint64_t gaps = 0;               ///< Deltas whose seq skipped one while in sync.
  uint64_t resyncs = 0;            ///< Times the replica lost sync (gap, mismatch, bad delta) and
                                   ///< had to wait for a snapshot.
  uint64_t stale_snapshots = 0;    ///< Snapshots superseded before confirmation (e.g. the
                                   ///< TRANSIENT_LOCAL replay of an old keyframe on joining).
  uint64_t unknown_topology = 0;   ///< Deltas for a topology version we do not hold.
  uint64_t malformed = 0;          ///< Samples that failed to decode or were inconsistent.
  uint64_t oversized = 0;          ///< Samples above the type's size limit.
  uint64_t foreign_session = 0;    ///< Samples of another session (envelope or payload).
  uint64_t ignored = 0;            ///< Stale or unsynced deltas, snapshots behind our state.
  uint64_t status = 0;             ///< Status messages received.
  uint64_t malformed_observed = 0; ///< Applied frames whose session view was refused (tool count,
                                   ///< non-finite values, absurd blade length, negative
                                   ///< measures); the mesh stood.
  bool authenticated = false;      ///< A session key is configured: only signed samples are taken.
  uint64_t unsigned_samples = 0;   ///< Samples without a tag while a key is configured.
  uint64_t forged = 0;             ///< Samples whose tag does not verify (wrong key, altered).
  uint64_t replayed = 0;           ///< Authentic samples not newer than one already taken.
  uint64_t invalid_epoch = 0;      ///< Authentic samples whose epoch is after their signing time.
  uint64_t other_server = 0;       ///< Samples of an older server epoch while the followed server
                                   ///< is alive (a second server on the session).
  uint64_t server_changes = 0;     ///< Times a newer server epoch took over (a restarted server).
  uint64_t samples = 0;            ///< Samples received of this session (any topic).
  uint64_t bytes_received = 0;     ///< Payload bytes of those samples.
};

/// Readers of one session's snapshot, delta and status topics feeding a
/// `MeshReplica`. Not thread-safe.
///
/// Authentication: with the session key every sample's signed trailer is
/// checked on the raw payload before it is parsed (stream_auth.h); unsigned
/// and forged samples are counted and dropped, so nothing without the key
/// reaches the replica. Every sample then passes one `EpochGate` (no window:
/// late joiners are sent an old keyframe; one lane per topic): the viewer
/// follows one server epoch. A newer epoch (a restarted server) takes over
/// and the replica waits for its snapshot; an older one is refused while the
/// followed server has been heard within `kServerQuietNs`; a sequence number
/// of another epoch, however high, never takes the replica over. Without a
/// key (an open session) the same rules apply to the epochs the samples
/// claim, which anyone on the network can forge.
class MeshStreamSubscriber {
 public:
  /// Throws `InputError` ("--session") on an invalid session name. With a
  /// `key`, only samples signed with it are taken (see the class comment).
  MeshStreamSubscriber(DdsParticipant& participant, std::string session,
                       std::optional<SessionKey> key = std::nullopt);
  ~MeshStreamSubscriber();
  MeshStreamSubscriber(const MeshStreamSubscriber&) = delete;
  MeshStreamSubscriber& operator=(const MeshStreamSubscriber&) = delete;

  /// Waits up to `timeout` for any sample (one WaitSet over the three
  /// readers), then processes everything available. Returns the number of
  /// samples of this session processed. Never throws for sample contents.
  size_t Poll(std::chrono::nanoseconds timeout);

  /// Feeds one payload as if it arrived on `kind`'s topic with envelope key
  /// `session` and sequence `seq` (tests, fuzzing, log replay).
  void Process(EnvelopeKind kind, std::string_view session, uint64_t seq,
               std::span<const uint8_t> payload);

  [[nodiscard]] const MeshReplica& replica() const { return replica_; }
  /// True when the replica is in sync and confirmed current: a delta has
  /// applied on top of the latest snapshot, or no delta came for
  /// `confirm_timeout` after it (a paused publisher). A TRANSIENT_LOCAL
  /// replay of an old keyframe is therefore never reported as current.
  [[nodiscard]] bool current() const;
  /// Incremented whenever the replica's state changes.
  [[nodiscard]] uint64_t state_version() const { return state_version_; }
  [[nodiscard]] const MeshStreamSubscriberStats& stats() const { return stats_; }
  [[nodiscard]] const std::optional<v1::SessionStatus>& last_status() const { return status_; }
  /// The session (clock, cuts, tools) as of the replica's frame: taken from
  /// each snapshot or delta applied, so it is as current as the mesh. Unset
  /// until the first one carries a valid view.
  [[nodiscard]] const std::optional<v1::ObserverSession>& observed() const { return observed_; }
  /// Monotonic ns of the last sample of this session, 0 if none yet.
  [[nodiscard]] int64_t last_sample_ns() const { return last_sample_ns_; }
  [[nodiscard]] const std::string& session() const { return session_; }
  void set_confirm_timeout(std::chrono::milliseconds t) { confirm_timeout_ = t; }

 private:
  static constexpr size_t kMaxPending = 64;
  static constexpr int64_t kServerQuietNs = 3'000'000'000;
  static constexpr int kMaxObservedTools = 4;
  static constexpr double kMaxObservedBladeLength = 1.0;  // m

  void OnSnapshot(std::span<const uint8_t> payload, uint64_t seq);
  void OnDelta(std::span<const uint8_t> payload, uint64_t seq);
  void OnStatus(std::span<const uint8_t> payload, uint64_t seq);
  /// Applies or stashes a delta; false if it was refused (malformed, unknown
  /// topology, hash mismatch).
  bool HandleDelta(const v1::MeshDelta& delta);
  void Stash(const v1::MeshDelta& delta);
  void ApplyPending();
  void LoseSync();
  void TakeObserved(const v1::ObserverSession& observed);
  void CountForeign();
  bool Decodable(std::span<const uint8_t> payload, google::protobuf::MessageLite& msg,
                 EnvelopeKind kind);
  /// Checks the trailer (with a key); sets `*body` to the bytes to parse.
  bool Authentic(EnvelopeKind kind, std::span<const uint8_t> payload, std::span<const uint8_t>* body);
  /// Judges a decoded sample's epoch and sequence by the gate and switches to
  /// a new server epoch; false when the sample is to be dropped. The caller
  /// records the sample in the gate once its content proved valid.
  bool Admit(EnvelopeKind kind, uint64_t epoch, uint64_t seq, int64_t wall_ns);

  std::string session_;
  // Verifiers of the three topics (null in an open session), and the gate.
  std::unique_ptr<PayloadAuthenticator> verifiers_[3];
  EpochGate gate_{0, kServerQuietNs};
  uint64_t server_epoch_ = 0;  // epoch the replica's state comes from
  int64_t last_other_server_log_ns_ = 0;
  DdsTopic snapshot_topic_;
  DdsTopic delta_topic_;
  DdsTopic status_topic_;
  DdsReader snapshot_reader_;
  DdsReader delta_reader_;
  DdsReader status_reader_;
  struct WaitSet;
  std::unique_ptr<WaitSet> waitset_;

  MeshReplica replica_;
  std::optional<v1::ObserverSession> observed_;
  bool confirmed_ = false;
  int64_t snapshot_applied_ns_ = 0;
  std::chrono::milliseconds confirm_timeout_{1000};
  // Deltas that arrived ahead of the snapshot they follow (cross-topic
  // reordering while joining or resyncing), by seq; bounded.
  std::map<uint64_t, v1::MeshDelta> pending_;
  v1::MeshSnapshot snapshot_msg_;
  v1::MeshDelta delta_msg_;
  std::optional<v1::SessionStatus> status_;
  uint64_t state_version_ = 0;
  int64_t last_sample_ns_ = 0;
  uint64_t process_foreign_ = 0;  // foreign payloads seen by Process
  uint64_t reader_foreign_ = 0;   // foreign envelopes dropped by the readers
  MeshStreamSubscriberStats stats_;
};

}  // namespace cutsim::transport
