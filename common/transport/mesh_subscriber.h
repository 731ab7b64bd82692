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
  uint64_t samples = 0;            ///< Samples received of this session (any topic).
  uint64_t bytes_received = 0;     ///< Payload bytes of those samples.
};

/// Readers of one session's snapshot, delta and status topics feeding a
/// `MeshReplica`. Not thread-safe.
class MeshStreamSubscriber {
 public:
  /// Throws `InputError` ("--session") on an invalid session name.
  MeshStreamSubscriber(DdsParticipant& participant, std::string session);
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
  static constexpr int kMaxObservedTools = 4;
  static constexpr double kMaxObservedBladeLength = 1.0;  // m

  void OnSnapshot(std::span<const uint8_t> payload, uint64_t seq);
  void OnDelta(std::span<const uint8_t> payload, uint64_t seq);
  void OnStatus(std::span<const uint8_t> payload);
  void HandleDelta(const v1::MeshDelta& delta);
  void Stash(const v1::MeshDelta& delta);
  void ApplyPending();
  void LoseSync();
  void TakeObserved(const v1::ObserverSession& observed);
  void CountForeign();
  bool Decodable(std::span<const uint8_t> payload, google::protobuf::MessageLite& msg,
                 EnvelopeKind kind);

  std::string session_;
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
