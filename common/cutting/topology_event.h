#pragma once
/// @file
/// What one executed cut step changed, in the order the FEM side must apply
/// it. Events are deterministic: replaying them in order on a fresh copy of
/// the uncut mesh (CutMesh::ApplyEvent) reproduces the topology and rest
/// positions bit-exactly.

#include <cstdint>
#include <vector>

#include <Eigen/Core>

namespace cutsim::cutting {

/// `new_node` is a copy of `node` (rest and world position, velocity); the
/// listed tets stop using `node` and use `new_node` instead. New node ids are
/// consecutive in event order (N, N+1, …), so the FEM's AddNodeCopy returns
/// exactly `new_node` when splits are applied in order.
struct Split {
  int32_t node = -1;
  int32_t new_node = -1;
  std::vector<int32_t> tets;  ///< Retargeted tets, in application order.
};

/// Remeshing move of one node (method paper §3.3), applied after all splits.
struct Move {
  int32_t node = -1;
  Eigen::Vector3d rest = Eigen::Vector3d::Zero();   ///< New rest position, m.
  Eigen::Vector3d world = Eigen::Vector3d::Zero();  ///< New world position, m.
};

/// One cut step. The sim applies it with sim::ApplyEventToFem, in order: for
/// each split AddNodeCopy(node) (which must return new_node) then
/// RetargetTet for each listed tet (the corner whose index equals `node`);
/// for each move SetRestPosition + world position; then the elements and
/// stable-step leaves of the moved nodes' tets (a tet only re-pointed to a
/// copy keeps both: the copy starts at its original's rest and world
/// position) and RecomputeNodeMasses(touched_nodes). `touched_tets` also
/// lists the re-pointed ones, for observers.
struct TopologyEvent {
  uint64_t version = 0;               ///< Topology version after this event (1, 2, …).
  std::vector<Split> splits;
  std::vector<Move> moves;
  std::vector<int32_t> touched_tets;  ///< Sorted, unique: retargeted or moved.
  std::vector<int32_t> touched_nodes; ///< Sorted, unique: nodes whose mass changed.

  [[nodiscard]] bool empty() const { return splits.empty() && moves.empty(); }
};

}  // namespace cutsim::cutting
