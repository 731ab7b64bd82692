#pragma once
/// @file
/// Per-element shape measures: quality for reports and remeshing decisions,
/// shortest altitude/edge for the FEM's stable time step.

#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "common/mesh/tet_mesh.h"

namespace cutsim::mesh {

/// Mean-ratio quality η = 12·(3|V|)^(2/3) / Σ ℓᵢⱼ² of tet (x0..x3): scale
/// invariant, 1 for the regular tet, → 0 for slivers and needles; 0 if the
/// signed volume is ≤ 0 (inverted elements have no quality).
double MeanRatio(const Eigen::Vector3d& x0, const Eigen::Vector3d& x1, const Eigen::Vector3d& x2,
                 const Eigen::Vector3d& x3);

/// η³ = 1728·9V² / (Σ ℓᵢⱼ²)³, the cube of MeanRatio without its cube root:
/// the same order, for comparisons against thresholds (cubed) in loops
/// where cbrt is most of the cost. 0 if the signed volume is ≤ 0.
double MeanRatioCubed(const Eigen::Vector3d& x0, const Eigen::Vector3d& x1, const Eigen::Vector3d& x2,
                      const Eigen::Vector3d& x3);

/// Shortest altitude of the tet: min over faces of 3|V| / area, m.
double ShortestAltitude(const Eigen::Vector3d& x0, const Eigen::Vector3d& x1, const Eigen::Vector3d& x2,
                        const Eigen::Vector3d& x3);

/// Shortest edge of the tet, m.
double ShortestEdge(const Eigen::Vector3d& x0, const Eigen::Vector3d& x1, const Eigen::Vector3d& x2,
                    const Eigen::Vector3d& x3);

/// Per-tet measures of a mesh.
struct TetQuality {
  std::vector<double> mean_ratio;         // #T in [0, 1]
  std::vector<double> shortest_altitude;  // #T, m
  std::vector<double> shortest_edge;      // #T, m
};

/// All three measures for every tet. O(T).
TetQuality ComputeTetQuality(const TetMesh& mesh);

}  // namespace cutsim::mesh
