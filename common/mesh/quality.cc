#include "common/mesh/quality.h"

#include <algorithm>
#include <cmath>
#include <utility>

namespace cutsim::mesh {

using Eigen::Vector3d;

namespace {

// Signed volume and Σ ℓᵢⱼ² of tet (x0..x3), the two terms of the mean ratio.
std::pair<double, double> VolumeAndEdgeSum(const Vector3d& x0, const Vector3d& x1, const Vector3d& x2,
                                           const Vector3d& x3) {
  return {SignedVolume(x0, x1, x2, x3), (x1 - x0).squaredNorm() + (x2 - x0).squaredNorm() +
                                            (x3 - x0).squaredNorm() + (x2 - x1).squaredNorm() +
                                            (x3 - x1).squaredNorm() + (x3 - x2).squaredNorm()};
}

}  // namespace

double MeanRatio(const Vector3d& x0, const Vector3d& x1, const Vector3d& x2, const Vector3d& x3) {
  const auto [vol, sum_l2] = VolumeAndEdgeSum(x0, x1, x2, x3);
  if (!(vol > 0.0)) return 0.0;
  return std::min(1.0, 12.0 * std::cbrt(9.0 * vol * vol) / sum_l2);  // (3V)^(2/3) = cbrt(9V²)
}

double MeanRatioCubed(const Vector3d& x0, const Vector3d& x1, const Vector3d& x2, const Vector3d& x3) {
  const auto [vol, sum_l2] = VolumeAndEdgeSum(x0, x1, x2, x3);
  if (!(vol > 0.0)) return 0.0;
  return std::min(1.0, 1728.0 * 9.0 * vol * vol / (sum_l2 * sum_l2 * sum_l2));
}

double ShortestAltitude(const Vector3d& x0, const Vector3d& x1, const Vector3d& x2, const Vector3d& x3) {
  const double vol3 = 3.0 * std::abs(SignedVolume(x0, x1, x2, x3));
  const double max_area = 0.5 * std::max({(x2 - x1).cross(x3 - x1).norm(), (x2 - x0).cross(x3 - x0).norm(),
                                          (x1 - x0).cross(x3 - x0).norm(), (x1 - x0).cross(x2 - x0).norm()});
  return max_area > 0.0 ? vol3 / max_area : 0.0;  // the shortest altitude stands on the largest face
}

double ShortestEdge(const Vector3d& x0, const Vector3d& x1, const Vector3d& x2, const Vector3d& x3) {
  return std::sqrt(std::min({(x1 - x0).squaredNorm(), (x2 - x0).squaredNorm(), (x3 - x0).squaredNorm(),
                             (x2 - x1).squaredNorm(), (x3 - x1).squaredNorm(), (x3 - x2).squaredNorm()}));
}

TetQuality ComputeTetQuality(const TetMesh& mesh) {
  TetQuality q;
  const auto n = static_cast<size_t>(mesh.num_tets());
  q.mean_ratio.resize(n);
  q.shortest_altitude.resize(n);
  q.shortest_edge.resize(n);
  for (int32_t t = 0; t < mesh.num_tets(); ++t) {
    const Vector3d x0 = mesh.nodes.row(mesh.tets(t, 0)), x1 = mesh.nodes.row(mesh.tets(t, 1)),
                   x2 = mesh.nodes.row(mesh.tets(t, 2)), x3 = mesh.nodes.row(mesh.tets(t, 3));
    const auto i = static_cast<size_t>(t);
    q.mean_ratio[i] = MeanRatio(x0, x1, x2, x3);
    q.shortest_altitude[i] = ShortestAltitude(x0, x1, x2, x3);
    q.shortest_edge[i] = ShortestEdge(x0, x1, x2, x3);
  }
  return q;
}

}  // namespace cutsim::mesh
