#pragma once
/// @file
/// The server's end of the observer mesh stream: turns each viewer frame of
/// the mesh into a snapshot and/or a delta against the state last sent (the
/// encoding is described in mesh_stream.h).

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "common/mesh/mesh_frame.h"
#include "common/mesh/tet_mesh.h"
#include "common/transport/codec.h"
#include "common/transport/dds.h"
#include "common/transport/mesh_hash.h"
#include "common/transport/stream_auth.h"
#include "cutsim/v1/wire.pb.h"

namespace cutsim::transport {

/// One frame of the server's mesh, filled by the server in `PublishFrame`
/// (the same type the simulation fills; `debris` is not sent).
using MeshFrame = mesh::MeshFrame;

/// How often the publisher sends snapshots and how finely it quantises.
struct MeshStreamOptions {
  double keyframe_interval_s = 2.0;  ///< Periodic snapshot, s (≤ 0: only on join / topology).
  double quantum_m = 1e-5;           ///< Position quantum, m.
  /// A node is sent when its world position is farther than this from the
  /// value last sent for it, m; unset = quantum_m.
  std::optional<double> move_tolerance_m;
  /// The session key: every snapshot, delta and status is signed with it
  /// (stream_auth.h). Unset: an open session, nothing is signed.
  std::optional<SessionKey> key;
};

/// The publisher's counters (`MeshStreamPublisher::stats`).
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
  /// True when a reader of the status topic is matched (a viewer, or a lab
  /// bridge's session directory that watches no mesh).
  [[nodiscard]] bool HasStatusReaders() const;
  /// This publisher's epoch (its start, CLOCK_REALTIME ns): viewers follow
  /// one epoch per session.
  [[nodiscard]] uint64_t epoch() const { return epoch_; }

  /// Called once per viewer frame. `fill` is invoked only when at least one
  /// reader is matched (no copying, no encoding otherwise); it fills the
  /// reused `MeshFrame` (resize in place, storage kept between frames).
  /// Publishes a snapshot when a new reader matched, the keyframe interval
  /// elapsed, or the topology changed beyond what a delta carries, and the
  /// frame's delta whenever a delta can carry the change. Never throws for
  /// frame contents: an inconsistent frame (sizes, out-of-range indices) is
  /// logged and skipped; non-finite coordinates are quantised like any
  /// other (NaN to 0, ±∞ clamped, see `Quantise`).
  void PublishFrame(const std::function<void(MeshFrame&)>& fill);

  /// The session as observers see it (clock, cuts, tools), sent with every
  /// following snapshot and delta until set again, so a late joiner gets it
  /// with its first snapshot. Copies into storage kept between frames;
  /// call before PublishFrame.
  void SetObserved(const v1::ObserverSession& observed) { observed_.CopyFrom(observed); }

  /// Publishes a status message (session is filled in). Never throws.
  void PublishStatus(const cutsim::v1::SessionStatus& status);

  [[nodiscard]] MeshStreamStats stats() const { return stats_; }
  [[nodiscard]] const std::string& session() const { return session_; }
  [[nodiscard]] const MeshStreamOptions& options() const { return opts_; }
  /// Quantised world positions as last sent (what viewers hold), for tests.
  [[nodiscard]] const QuantisedPositions& sent_world() const { return sent_world_; }

 private:
  // Frame checks.
  bool ValidFrame() const;
  bool NoteReaders(uint32_t readers_total);
  bool KeyframeDue(int64_t now_ns) const;
  bool DeltaPossible() const;
  // The delta against the state last sent; each step also updates that state.
  void BuildDelta();
  void GrowSentNodes(Eigen::Index n);
  void FindChangedTets();
  bool SurfaceChanged() const;
  void AddChangedTets();
  void AddRestChanges(Eigen::Index old_n);
  void AddMovedNodes(Eigen::Index old_n);
  void AddSurface();
  void AddStressChanges();
  // The whole frame as the state sent (first frame, or beyond a delta).
  void TakeFrameAsSent();
  // Encoding and writing.
  void EncodeSnapshot(uint64_t seq, uint64_t hash);
  void PublishDelta(uint64_t seq, uint64_t hash);

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
  uint64_t epoch_ = 0;  // this server's start, CLOCK_REALTIME ns (stream_auth.h)
  // Signers of the three topics; null in an open session.
  std::unique_ptr<PayloadAuthenticator> snapshot_signer_;
  std::unique_ptr<PayloadAuthenticator> delta_signer_;
  std::unique_ptr<PayloadAuthenticator> status_signer_;
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
  v1::ObserverSession observed_;
  Encoder encoder_;
  MeshStreamStats stats_;
};

}  // namespace cutsim::transport
