#pragma once
/// @file
/// The observers' mesh stream: the server publishes snapshots and deltas of
/// its mesh over DDS (`MeshStreamPublisher`), viewers rebuild the exact mesh
/// (`MeshStreamSubscriber` → `MeshReplica`) and verify it by hash.
///
/// Encoding (both sides in this file; see mesh_stream.cc for the details):
///  - World and rest positions are quantised to integers k = round(x/quantum)
///    (default quantum 10 µm), clamped to |k| ≤ 2^22 (±42 m at 10 µm) so a
///    float carries k·quantum exactly. The state *as sent* is these integers.
///  - A snapshot (MeshSnapshot) carries everything: rest and world as floats
///    of k·quantum, tets, surface, opened flags, topology version, stress codes.
///  - A delta (MeshDelta) carries, against the state last sent:
///      * topology diffs when tets, surface, opened flags or the node count
///        changed: new node count (nodes are only appended), the changed tet
///        rows (indices sorted and delta-coded), the nodes whose quantised rest
///        changed (new nodes included, delta-coded against the previous sent
///        value, 0 for a new node), and the whole surface + opened flags when
///        they changed. CutEvent messages are not used: the publisher sees
///        states, not events, and a diff is exact whatever the cut code did.
///      * moved nodes: nodes whose world position is more than
///        `move_tolerance_m` away from the value last sent for them (new nodes
///        always), indices sorted and delta-coded, positions as the zigzag
///        (sint32) change of the quantised value.
///      * stress codes (log scale, see `StressCode`) of nodes whose code changed.
///      * the hash after applying.
///    A node count that shrinks or a tet count that changes cannot be a delta:
///    the publisher sends a snapshot instead.
///  - Sequence numbers: one counter per published frame. The delta chain is
///    unbroken: a frame that publishes a snapshot (new reader, keyframe,
///    topology beyond a delta) also publishes that frame's delta, so viewers
///    already in sync never see a gap. A delta with seq s applies to the state
///    at seq s−1; a snapshot with seq s is the state at seq s.
///  - Hash (`MeshHash`): a 64-bit hash of topology version, quantised world
///    positions, tets, surface and opened flags. Rest positions and stress are
///    display data and are not hashed.

#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "common/mesh/tet_mesh.h"
#include "common/transport/codec.h"
#include "common/transport/dds.h"
#include "cutsim/v1/wire.pb.h"

namespace cutsim::transport {

/// One frame of the server's mesh, filled by the server in `PublishFrame`.
struct MeshFrame {
  uint64_t frame = 0;             ///< Physics frame number.
  double sim_time = 0.0;          ///< s.
  uint64_t topology_version = 0;  ///< Bumped by every topology change.
  mesh::Positions world;          ///< #N×3, m.
  mesh::Positions rest;           ///< #N×3, m.
  mesh::Tets tets;                ///< #T×4.
  mesh::Triangles surface;        ///< #F×3 boundary triangles.
  std::vector<uint8_t> opened;    ///< #F, non-zero = face opened by a cut (or empty = none).
  std::vector<double> stress;     ///< #N optional per-node scalar (e.g. von Mises, Pa), may be empty.
};

/// Quantised coordinates, one row per node.  // #N×3
using QuantisedPositions = Eigen::Matrix<int32_t, Eigen::Dynamic, 3, Eigen::RowMajor>;

/// Largest |k| of a quantised coordinate: k·quantum is exact in a float.
inline constexpr int32_t kMaxQuantised = 1 << 22;

/// round(x / quantum), clamped to ±kMaxQuantised; NaN gives 0.
[[nodiscard]] int32_t Quantise(double x, double quantum);

/// Per-node stress code: sign(s)·round(16·log2(1 + |s|/1 Pa)), clamped to
/// ±65535 (about 6 % resolution, any magnitude up to 10^1230 Pa). NaN → 0.
[[nodiscard]] int32_t StressCode(double s);
/// Inverse of `StressCode` (the centre of the code's interval), Pa.
[[nodiscard]] double StressFromCode(int32_t code);

/// The hash of a mesh state as sent. Both sides compute it with this function.
/// `opened` may be empty (no face opened) — it hashes like all zeros.
[[nodiscard]] uint64_t MeshHash(uint64_t topology_version, const QuantisedPositions& world_q,
                                const mesh::Tets& tets, const mesh::Triangles& surface,
                                std::span<const uint8_t> opened);
/// The two halves `MeshHash` combines, for callers that cache the topology part.
[[nodiscard]] uint64_t TopologyHash(uint64_t topology_version, const mesh::Tets& tets,
                                    const mesh::Triangles& surface, std::span<const uint8_t> opened);
[[nodiscard]] uint64_t PositionsHash(const QuantisedPositions& world_q);
[[nodiscard]] uint64_t CombineHashes(uint64_t topology_hash, uint64_t positions_hash);

// ---------------------------------------------------------------------------
// Publisher (server side)

struct MeshStreamOptions {
  double keyframe_interval_s = 2.0;  ///< Periodic snapshot, s (≤ 0: only on join / topology).
  double quantum_m = 1e-5;           ///< Position quantum, m.
  /// A node is sent when its world position is farther than this from the
  /// value last sent for it, m; unset = quantum_m.
  std::optional<double> move_tolerance_m;
};

struct MeshStreamStats {
  uint64_t frames = 0;               ///< PublishFrame calls.
  uint64_t skipped_no_reader = 0;    ///< Frames with no matched reader: fill not called, nothing encoded.
  uint64_t snapshots = 0;            ///< Snapshots published.
  uint64_t deltas = 0;               ///< Deltas published.
  uint64_t snapshot_bytes = 0;       ///< Payload bytes of all snapshots.
  uint64_t delta_bytes = 0;          ///< Payload bytes of all deltas.
  uint64_t last_snapshot_bytes = 0;  ///< Payload bytes of the latest snapshot.
  uint64_t last_delta_bytes = 0;     ///< Payload bytes of the latest delta.
  uint64_t publish_failures = 0;     ///< Writes refused or failed (e.g. slow reader, too large).
  uint64_t status_published = 0;
  int64_t encode_ns = 0;             ///< Total time in PublishFrame after fill (diff + encode + write).
  int64_t last_encode_ns = 0;        ///< The same, latest frame.
  uint64_t last_seq = 0;             ///< Sequence number of the latest frame published.
  uint64_t last_hash = 0;            ///< Hash of the latest frame published.
};

/// Publishes one session's mesh. Not thread-safe: call from one thread.
class MeshStreamPublisher {
 public:
  /// Throws `InputError` on an invalid session name ("--session") or options.
  MeshStreamPublisher(DdsParticipant& participant, std::string session,
                      MeshStreamOptions opts = {});
  ~MeshStreamPublisher();
  MeshStreamPublisher(const MeshStreamPublisher&) = delete;
  MeshStreamPublisher& operator=(const MeshStreamPublisher&) = delete;

  /// True when a reader of the snapshot or delta topic is matched.
  [[nodiscard]] bool HasReaders() const;

  /// Called once per viewer frame. `fill` is invoked only when at least one
  /// reader is matched (no copying, no encoding otherwise); it fills the
  /// reused `MeshFrame` (resize in place, storage kept between frames).
  /// Publishes a snapshot when a new reader matched, the keyframe interval
  /// elapsed, or the topology changed beyond what a delta carries, and the
  /// frame's delta in every case. Never throws for frame contents: an
  /// inconsistent frame (sizes, out-of-range indices, non-finite values)
  /// is logged and skipped.
  void PublishFrame(const std::function<void(MeshFrame&)>& fill);

  /// Publishes a status message (session is filled in). Never throws.
  void PublishStatus(const cutsim::v1::SessionStatus& status);

  [[nodiscard]] MeshStreamStats stats() const { return stats_; }
  [[nodiscard]] const std::string& session() const { return session_; }
  [[nodiscard]] const MeshStreamOptions& options() const { return opts_; }
  /// Quantised world positions as last sent (what viewers hold), for tests.
  [[nodiscard]] const QuantisedPositions& sent_world() const { return sent_world_; }

 private:
  bool ValidFrame() const;
  void EncodeSnapshot(uint64_t seq, uint64_t hash);

  std::string session_;
  MeshStreamOptions opts_;
  double tolerance2_;  // m², squared move tolerance
  DdsTopic snapshot_topic_;
  DdsTopic delta_topic_;
  DdsTopic status_topic_;
  DdsWriter snapshot_writer_;
  DdsWriter delta_writer_;
  DdsWriter status_writer_;

  MeshFrame frame_;  // filled by the caller, reused
  // State last sent (what every synced viewer holds).
  bool have_sent_ = false;
  uint64_t seq_ = 0;
  uint64_t status_seq_ = 0;
  uint64_t sent_version_ = 0;
  QuantisedPositions sent_world_;  // #N×3
  QuantisedPositions sent_rest_;   // #N×3
  mesh::Tets sent_tets_;
  mesh::Triangles sent_surface_;
  std::vector<uint8_t> sent_opened_;  // #F (0/1)
  std::vector<int32_t> sent_stress_;  // #N codes, empty = none
  uint64_t topology_hash_ = 0;
  uint32_t seen_readers_total_ = 0;  // snapshot + delta writers' cumulative matches
  int64_t last_snapshot_ns_ = 0;

  // Reused scratch.
  std::vector<int32_t> changed_tets_;
  v1::MeshSnapshot snapshot_;
  v1::MeshDelta delta_;
  v1::SessionStatus status_;
  Encoder encoder_;
  MeshStreamStats stats_;
};

// ---------------------------------------------------------------------------
// Replica (viewer side)

/// The mesh rebuilt from snapshots and deltas.
class MeshReplica {
 public:
  enum class SnapshotResult : uint8_t {
    kApplied = 0,
    kHashMismatch,  ///< Decoded, but its hash disagrees: not applied.
    kMalformed,     ///< Inconsistent sizes / indices / quantum: not applied.
  };
  enum class DeltaResult : uint8_t {
    kApplied = 0,
    kGap,              ///< seq is not the next one: not applied, replica out of sync.
    kHashMismatch,     ///< Applied, but the hash disagrees: replica out of sync.
    kUnknownTopology,  ///< base_topology_version is not ours: not applied, state kept.
    kMalformed,        ///< Inconsistent content: not applied, state kept (a genuine
                       ///< delta with this seq may still follow; if none does the
                       ///< next one is a gap).
    kStale,            ///< seq at or before ours (duplicate or old): ignored, state kept.
    kNotSynced,        ///< No state to apply it to (waiting for a snapshot): ignored.
  };

  /// Replaces the whole state. Validates before touching anything.
  SnapshotResult ApplySnapshot(const v1::MeshSnapshot& snapshot);
  /// Applies a delta to the state at seq − 1.
  DeltaResult ApplyDelta(const v1::MeshDelta& delta);

  /// True when the state is a verified copy of the publisher's (seq()).
  [[nodiscard]] bool synced() const { return synced_; }
  [[nodiscard]] uint64_t seq() const { return seq_; }
  [[nodiscard]] uint64_t frame() const { return frame_; }
  [[nodiscard]] double sim_time() const { return sim_time_; }
  [[nodiscard]] uint64_t topology_version() const { return version_; }
  [[nodiscard]] uint64_t hash() const { return hash_; }
  [[nodiscard]] double quantum() const { return quantum_; }
  [[nodiscard]] const QuantisedPositions& world_q() const { return world_q_; }
  [[nodiscard]] const QuantisedPositions& rest_q() const { return rest_q_; }
  /// World positions k·quantum, m (#N×3).
  [[nodiscard]] const mesh::Positions& world() const { return world_; }
  [[nodiscard]] mesh::Positions Rest() const;
  [[nodiscard]] const mesh::Tets& tets() const { return tets_; }
  [[nodiscard]] const mesh::Triangles& surface() const { return surface_; }
  [[nodiscard]] const std::vector<uint8_t>& opened() const { return opened_; }
  /// Per-node stress decoded from codes, Pa; empty when the stream has none.
  [[nodiscard]] const std::vector<double>& stress() const { return stress_; }
  /// Recomputes the hash of the current state (tests).
  [[nodiscard]] uint64_t ComputeHash() const;
  /// Forgets the state (next snapshot required).
  void Desync() { synced_ = false; }

 private:
  bool synced_ = false;
  uint64_t seq_ = 0;
  uint64_t frame_ = 0;
  double sim_time_ = 0.0;
  uint64_t version_ = 0;
  uint64_t hash_ = 0;
  uint64_t topology_hash_ = 0;
  double quantum_ = 0.0;
  QuantisedPositions world_q_;
  QuantisedPositions rest_q_;
  mesh::Positions world_;
  mesh::Tets tets_;
  mesh::Triangles surface_;
  std::vector<uint8_t> opened_;
  std::vector<int32_t> stress_code_;
  std::vector<double> stress_;
};

// ---------------------------------------------------------------------------
// Subscriber (viewer side)

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
  /// Monotonic ns of the last sample of this session, 0 if none yet.
  [[nodiscard]] int64_t last_sample_ns() const { return last_sample_ns_; }
  [[nodiscard]] const std::string& session() const { return session_; }
  void set_confirm_timeout(std::chrono::milliseconds t) { confirm_timeout_ = t; }

 private:
  static constexpr size_t kMaxPending = 64;

  void OnSnapshot(std::span<const uint8_t> payload, uint64_t seq);
  void OnDelta(std::span<const uint8_t> payload, uint64_t seq);
  void OnStatus(std::span<const uint8_t> payload);
  void HandleDelta(const v1::MeshDelta& delta);
  void Stash(const v1::MeshDelta& delta);
  void ApplyPending();
  void LoseSync();
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
