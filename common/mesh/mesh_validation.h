#pragma once
/// @file
/// Checks that turn a raw mesh (from a file or a generator) into a `TetMesh`
/// the FEM can trust, and the orientation fix readers apply first.

#include <cstdint>
#include <string_view>
#include <vector>

#include "common/mesh/tet_mesh.h"

namespace cutsim::mesh {

/// Where the rows of a mesh came from, so errors can name what the user sees
/// in the file. Every vector is optional (empty = use the 1-based row index).
struct MeshOrigin {
  std::vector<int64_t> node_ids;   ///< #N file ids of the nodes.
  std::vector<int64_t> tet_ids;    ///< #T file ids of the tets.
  std::vector<int64_t> tet_lines;  ///< #T 1-based line of each tet in a text file.
};

/// Largest mesh any reader, generator or cut accepts: nodes and tets. Every
/// reader and generator checks its counts against these before allocating.
inline constexpr int64_t kMaxMeshNodes = 2'000'000;
inline constexpr int64_t kMaxMeshTets = 10'000'000;

/// Throws `InputError` naming `source_name` if `nodes` or `tets` is negative or
/// exceeds kMaxMeshNodes / kMaxMeshTets.
void CheckMeshSize(int64_t nodes, int64_t tets, std::string_view source_name);

/// Throws `InputError` naming `source_name` and the offending node/element if
/// `mesh` has: no tets, an index out of range, a NaN/Inf coordinate, a tet with
/// zero or negative volume (|6V| ≤ 1e-12·ℓmax³ counts as zero), more nodes
/// or tets than the caps above, a node used
/// by no tet, a tet listed twice (same node set), a `regions` vector of the
/// wrong length, or a face shared by more than two tets. O(N + T).
void ValidateTetMesh(const TetMesh& mesh, std::string_view source_name,
                     const MeshOrigin& origin = {});

/// Throws `InputError` naming `source_name` and the node or element if the
/// mesh is not one whole piece of tissue: two nodes at exactly the same
/// position (a crack, as a cut mesh written out has), or a fold (two tets
/// sharing a face lie on the same side of it, so they overlap). For meshes a
/// scene starts from; a cut mesh read back for inspection legitimately has
/// coincident nodes. O(N log N + T log T).
void CheckWholeMesh(const TetMesh& mesh, std::string_view source_name, const MeshOrigin& origin = {});

/// Flips every tet with negative signed volume (swaps its nodes 1 and 2), for
/// files written with the opposite orientation. Zero-volume tets are left for
/// `ValidateTetMesh` to reject. Returns how many tets were flipped.
int64_t OrientTets(TetMesh& mesh);

/// Index of the first face (as tet·4 + local face) shared by more than two
/// tets, or −1 if every face of `tets` belongs to at most two tets. O(T).
int64_t FindOvershardFace(const Tets& tets);

}  // namespace cutsim::mesh
