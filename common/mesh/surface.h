#pragma once
/// @file
/// Boundary surface of a tet mesh and the topological checks the cutting code
/// runs after every cut.

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "common/mesh/tet_mesh.h"

namespace cutsim::mesh {

/// Boundary triangles of a tet mesh, each with the tet that owns it.
struct Surface {
  Triangles tris;                  // #F×3, counter-clockwise seen from outside
  std::vector<int32_t> tet;        // #F owning tet
  std::vector<int8_t> local_face;  // #F local face in 0..3 (the face opposite that local node)
};

/// Local face `f` (opposite node f) of a positively oriented tet as three
/// local node indices, counter-clockwise seen from outside the tet.
std::array<int, 3> LocalTetFace(int f);

/// Faces used by exactly one tet, oriented outward, in tet order (so the result
/// is deterministic). Requires positively oriented tets. O(T) with a hash of
/// sorted face keys.
Surface ExtractSurface(const Tets& tets);

/// Result of `CheckClosedManifold`.
struct ManifoldCheck {
  bool ok = false;      ///< Closed, edge- and vertex-manifold, consistently oriented.
  std::string problem;  ///< Why not, naming a triangle/edge/vertex; empty if ok.
  int64_t num_vertices = 0;  ///< Vertices used by the triangles.
  int64_t num_edges = 0;     ///< Undirected edges.
  int64_t num_faces = 0;     ///< Triangles.
  /// V − E + F (2 for each sphere-like component).
  [[nodiscard]] int64_t euler_characteristic() const { return num_vertices - num_edges + num_faces; }
};

/// Checks that `tris` is a closed, consistently oriented 2-manifold: every
/// directed edge appears exactly once and its reverse exactly once (so every
/// edge has two triangles with opposite orientation), no degenerate triangle,
/// and the triangles around every vertex form a single fan. O(F).
ManifoldCheck CheckClosedManifold(const Triangles& tris);

}  // namespace cutsim::mesh
