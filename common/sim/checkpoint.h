#pragma once
/// @file
/// Checkpoint files of the server: the cut tissue (every topology event in
/// order, replayed on the uncut scene mesh) plus every stage's part of the
/// state (stage.h: positions, velocities, the step's estimator, the tool's
/// contact and grip, the cut test's anchor, the measures), in a framed
/// protobuf (proto/cutsim/v1/checkpoint.proto).
/// Writes are atomic (temporary file, fsync, rename), so a crash while
/// writing leaves the previous checkpoint intact. Reads reject a corrupted,
/// truncated or foreign file with an InputError naming the file and field,
/// before anything is applied.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <span>
#include <string>
#include <vector>

#include "common/core/hash.h"  // Fnv1a64
#include "common/cutting/cut_mesh.h"
#include "common/cutting/topology_event.h"
#include "common/fem/state.h"
#include "common/mesh/tet_mesh.h"
#include "common/sim/simulation.h"
#include "cutsim/v1/checkpoint.pb.h"

namespace cutsim::sim {

/// Topology event ⇄ its checkpoint message. EventFromProto checks the shape
/// (3 coordinates per move, finite values) and throws InputError naming
/// `source` and `field` (e.g. "events[3].moves[0].rest").
[[nodiscard]] v1::CheckpointEvent EventToProto(const cutting::TopologyEvent& event);
[[nodiscard]] cutting::TopologyEvent EventFromProto(const v1::CheckpointEvent& event, const std::string& source,
                                                    const std::string& field);

// ---- the state a checkpoint keeps (Simulation::CheckpointState) ----------

/// What identifies the uncut scene a checkpoint belongs to.
struct CheckpointIdentity {
  std::string scene_name;
  uint64_t fingerprint = 0;  ///< SceneFingerprint
  std::string precision;     ///< "float" or "double"
  int32_t initial_nodes = 0;
  int32_t initial_tets = 0;
};

/// Hash of the scene's name, the node capacity and the reordered uncut mesh.
[[nodiscard]] uint64_t SceneFingerprint(const std::string& scene_name, int32_t node_capacity,
                                        const mesh::TetMesh& mesh);

/// A checkpoint body with `identity` and the frame count; the stages add
/// their parts (stage.h).
[[nodiscard]] v1::CheckpointBody MakeCheckpointBody(const CheckpointIdentity& identity, int64_t frames);

/// The simulation a checkpoint is restored into.
struct RestoreTarget {
  const CheckpointIdentity& identity;
  const cutting::CutMesh* cut = nullptr;  ///< its cut complex (null without cutting)
  int32_t num_nodes = 0;
  int32_t num_tets = 0;
  int32_t node_capacity = 0;
  bool fresh = true;  ///< no frame stepped and no event applied yet
};

/// Checks `body` against `target` (scene, mesh, precision, counters) and
/// replays its events on a copy of the cut complex, so a bad event is
/// reported before the real mesh or the FEM changes; then the sizes and
/// values of the positions and velocities. Returns the events, ready to
/// apply. Throws InputError naming `source` and the field; changes nothing.
[[nodiscard]] std::vector<cutting::TopologyEvent> CheckCheckpointBody(const v1::CheckpointBody& body,
                                                                      const std::string& source,
                                                                      const RestoreTarget& target);

/// Converts `events` and replays them in order on a copy of `start`: each
/// version above the last and at most kMaxTopologyVersion, every split and
/// move valid on the complex, touched tets below `num_tets` and touched
/// nodes below the replayed node count, which may not exceed
/// `node_capacity`. Returns the events, ready to apply, and sets `num_nodes`
/// to the replayed complex's node count. Throws InputError naming `source`
/// and the event's field; changes nothing.
[[nodiscard]] std::vector<cutting::TopologyEvent> CheckEvents(std::span<const NamedEvent> events,
                                                              const std::string& source,
                                                              const cutting::CutMesh& start, int32_t num_tets,
                                                              int32_t node_capacity, int32_t& num_nodes);

/// Applies `event` to a cut complex, first bumping its version across cut
/// steps that changed nothing (their empty events are not recorded).
void ReplayEvent(cutting::CutMesh& cut, const cutting::TopologyEvent& event);

// ---- files ------------------------------------------------------------------

/// Frames and writes `body` atomically: `path`.tmp, fsync, rename onto
/// `path`, fsync of the directory (the rename is on disk before anything
/// that relies on it, such as the event journal's restart). Throws InputError (file error) when the directory is not writable.
void WriteCheckpointFile(const std::filesystem::path& path, const v1::CheckpointBody& body);

/// Reads and checks a checkpoint file (magic, format version, checksum,
/// body). Throws InputError naming the file and field; a file of another
/// format version (e.g. 1, before the stages' parts) is refused naming both
/// versions.
[[nodiscard]] v1::CheckpointBody ReadCheckpointFile(const std::filesystem::path& path);

/// Saves `sim` to `path` (CheckpointState + WriteCheckpointFile) with the
/// session's `lineage` (see checkpoint.proto); returns what it wrote.
v1::CheckpointBody SaveCheckpoint(const Simulation& sim, const std::filesystem::path& path, uint64_t lineage = 0);

/// Restores `path` into `sim`, freshly created from the checkpoint's scene.
/// On an InputError nothing has been applied.
void RestoreCheckpoint(Simulation& sim, const std::filesystem::path& path);

/// Largest topology version a checkpoint may hold (events are replayed one
/// version at a time on restore).
inline constexpr uint64_t kMaxTopologyVersion = 10'000'000;
/// Largest checkpoint file read, bytes (1 GiB).
inline constexpr uint64_t kMaxCheckpointBytes = uint64_t{1} << 30;

/// The version of the last event `body` holds (0 without events): an event
/// journal continuing it holds the events after this one.
[[nodiscard]] uint64_t LastEventVersion(const v1::CheckpointBody& body);

}  // namespace cutsim::sim
