#pragma once
/// @file
/// Node renumbering for cache locality of the FEM's scatter/gather.

#include <cstdint>
#include <vector>

#include "common/mesh/tet_mesh.h"

namespace cutsim::mesh {

/// A node renumbering; keep it to map user node sets (fixed nodes, probes).
struct NodePermutation {
  std::vector<int32_t> new_to_old;  ///< #N: new index i was node new_to_old[i].
  std::vector<int32_t> old_to_new;  ///< #N: node j becomes old_to_new[j].
};

/// Reverse Cuthill–McKee ordering of the node graph (nodes adjacent when they
/// share a tet); each connected component starts from a pseudo-peripheral
/// node. O(N + T·log) for the neighbour sorting.
NodePermutation ReverseCuthillMcKee(const TetMesh& mesh);

/// Renumbers `mesh.nodes` and the indices in `mesh.tets` by `perm`; tet order
/// and regions are unchanged.
void ApplyNodePermutation(TetMesh& mesh, const NodePermutation& perm);

/// Maps old node indices to new ones (for user node sets).
std::vector<int32_t> MapNodeIndices(const std::vector<int32_t>& old_indices, const NodePermutation& perm);

/// Bandwidth of the node graph: max over tets of (max index − min index).
int32_t Bandwidth(const Tets& tets);

}  // namespace cutsim::mesh
