#pragma once
/// @file
/// The viewer's copy of the server's mesh, rebuilt from the observer stream's
/// snapshots and deltas (encoding in mesh_stream.h) and verified by hash
/// after every change.

#include <cstdint>
#include <vector>

#include "common/mesh/tet_mesh.h"
#include "common/transport/mesh_hash.h"
#include "cutsim/v1/wire.pb.h"

namespace cutsim::transport {

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
  /// A delta's node and tet indices, decoded from their delta coding; reused
  /// so that applying a delta allocates only when the mesh grows.
  struct DeltaIndices {
    std::vector<uint32_t> tets;
    std::vector<uint32_t> rest;
    std::vector<uint32_t> moved;
    std::vector<uint32_t> stress;
  };

  // Checks of a delta, before anything changes.
  bool DecodeDelta(const v1::MeshDelta& d);
  bool DeltaInRange(const v1::MeshDelta& d) const;
  // Steps of applying a checked delta.
  void GrowNodes(uint64_t n);
  void ApplyChangedTets(const v1::MeshDelta& d);
  void ApplyRestChanges(const v1::MeshDelta& d);
  void ApplyMovedNodes(const v1::MeshDelta& d);
  void ApplySurface(const v1::MeshDelta& d);
  void ApplyStress(const v1::MeshDelta& d);

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
  DeltaIndices indices_;
};

}  // namespace cutsim::transport
