#pragma once
/// @file
/// The tetrahedral mesh: node positions and tets, nothing else. Shared by
/// every layer above (fem, cutting, sim, render) as the one mesh type.

#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>  // cross() is defined here, not in Core

namespace cutsim::mesh {

/// Node coordinates, one row per node, metres.  // #N×3
using Positions = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
/// Tet node indices, one row per tet.  // #T×4
using Tets = Eigen::Matrix<int32_t, Eigen::Dynamic, 4, Eigen::RowMajor>;
/// Triangle node indices, one row per triangle.  // #F×3
using Triangles = Eigen::Matrix<int32_t, Eigen::Dynamic, 3, Eigen::RowMajor>;

/// A linear tetrahedral mesh. Invariant after `ValidateTetMesh` (see
/// mesh_validation.h): every tet has positive signed volume, i.e.
/// (x1−x0)·((x2−x0)×(x3−x0)) > 0, indices are in range, no NaN coordinates.
struct TetMesh {
  Positions nodes;  // #N×3, m
  Tets tets;        // #T×4
  /// Optional per-tet region (material) tag; empty or #T entries.
  std::vector<int32_t> regions;

  [[nodiscard]] int32_t num_nodes() const { return static_cast<int32_t>(nodes.rows()); }
  [[nodiscard]] int32_t num_tets() const { return static_cast<int32_t>(tets.rows()); }
};

/// Signed volume of the tet (x0, x1, x2, x3): ((x1−x0)·((x2−x0)×(x3−x0)))/6, m³.
inline double SignedVolume(const Eigen::Vector3d& x0, const Eigen::Vector3d& x1,
                           const Eigen::Vector3d& x2, const Eigen::Vector3d& x3) {
  return (x1 - x0).dot((x2 - x0).cross(x3 - x0)) / 6.0;
}

/// Signed volume of tet `t` of `mesh`, m³.
inline double SignedVolume(const TetMesh& mesh, int32_t t) {
  const auto& T = mesh.tets;
  return SignedVolume(mesh.nodes.row(T(t, 0)).transpose(), mesh.nodes.row(T(t, 1)).transpose(),
                      mesh.nodes.row(T(t, 2)).transpose(), mesh.nodes.row(T(t, 3)).transpose());
}

}  // namespace cutsim::mesh
