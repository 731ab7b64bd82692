#pragma once
/// @file
/// Distance between two deformed triangle surfaces, for the accuracy study:
/// points sampled on one surface (every vertex and every triangle centroid)
/// are projected onto the other with mesh::TriangleBvh::ClosestPoint
/// (point-to-triangle, exact), in both directions.

#include <algorithm>
#include <cstdint>

#include <Eigen/Core>

#include "common/mesh/bvh.h"
#include "common/mesh/tet_mesh.h"

namespace cutsim::bench {

struct SurfaceDistance {
  double hausdorff = 0;  ///< Symmetric Hausdorff distance, m: max over both directions.
  double mean = 0;       ///< Mean of all sample distances (both directions), m.
  int64_t samples = 0;
};

namespace internal {

/// One direction: samples of (pa, ta) against the tree of the other surface.
inline void OneSided(const mesh::Positions& pa, const mesh::Triangles& ta, const mesh::TriangleBvh& tree_b,
                     double radius, SurfaceDistance& acc, double& sum) {
  const auto visit = [&](const Eigen::Vector3d& q) {
    const auto hit = tree_b.ClosestPoint(q, radius);
    const double d = hit ? hit->distance : radius;
    acc.hausdorff = std::max(acc.hausdorff, d);
    sum += d;
    ++acc.samples;
  };
  // Only vertices that belong to the surface (interior nodes are not samples).
  std::vector<uint8_t> on_surface(static_cast<size_t>(pa.rows()), 0);
  for (Eigen::Index f = 0; f < ta.rows(); ++f) {
    for (int k = 0; k < 3; ++k) on_surface[static_cast<size_t>(ta(f, k))] = 1;
    visit((pa.row(ta(f, 0)) + pa.row(ta(f, 1)) + pa.row(ta(f, 2))).transpose() / 3.0);
  }
  for (Eigen::Index n = 0; n < pa.rows(); ++n) {
    if (on_surface[static_cast<size_t>(n)]) visit(pa.row(n).transpose());
  }
}

}  // namespace internal

/// Symmetric distance between surface A (positions #NA×3, triangles #FA×3)
/// and surface B. `radius` caps the search (and the reported distance), m.
inline SurfaceDistance MeasureSurfaceDistance(const mesh::Positions& pa, const mesh::Triangles& ta,
                                              const mesh::Positions& pb, const mesh::Triangles& tb,
                                              double radius = 1.0) {
  const mesh::TriangleBvh tree_a(pa, ta), tree_b(pb, tb);
  SurfaceDistance out;
  double sum = 0;
  internal::OneSided(pa, ta, tree_b, radius, out, sum);
  internal::OneSided(pb, tb, tree_a, radius, out, sum);
  out.mean = out.samples > 0 ? sum / static_cast<double>(out.samples) : 0.0;
  return out;
}

}  // namespace cutsim::bench
