#pragma once
/// @file
/// Axis-aligned bounding-box tree over surface triangles: built once per
/// topology, refitted every step in O(F) without allocation, queried by the
/// tool-contact and blade code.

#include <cstdint>
#include <optional>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "common/mesh/tet_mesh.h"

namespace cutsim::mesh {

/// Closest point on the surface to a query point.
struct ClosestPointHit {
  int32_t tri = -1;          ///< Row of the triangle in the tree's triangle list.
  Eigen::Vector3d point;     ///< Closest point, m.
  Eigen::Vector3d bary;      ///< Barycentrics (w0, w1, w2) of `point` w.r.t. the triangle's nodes.
  double distance = 0.0;     ///< |point − query|, m.
};

/// Intersection of a segment a→b with a triangle.
struct SegmentHit {
  int32_t tri = -1;          ///< Row of the triangle.
  double t = 0.0;            ///< Segment parameter in [0, 1]: point = a + t (b − a).
  Eigen::Vector3d point;     ///< Intersection point, m.
  Eigen::Vector3d bary;      ///< Barycentrics of `point` in the triangle.
};

/// Closest point of triangle (p0, p1, p2) to `q` with barycentrics (Ericson,
/// Real-Time Collision Detection §5.1.5). Degenerate triangles are handled.
ClosestPointHit ClosestPointOnTriangle(const Eigen::Vector3d& q, const Eigen::Vector3d& p0,
                                       const Eigen::Vector3d& p1, const Eigen::Vector3d& p2);

/// Segment a→b against triangle (p0, p1, p2), Möller–Trumbore; both sides count.
std::optional<SegmentHit> IntersectSegmentTriangle(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                                                   const Eigen::Vector3d& p0, const Eigen::Vector3d& p1,
                                                   const Eigen::Vector3d& p2);

/// AABB tree over triangles. Triangle indices refer to the `tris` given at build.
class TriangleBvh {
 public:
  TriangleBvh() = default;
  /// Builds the tree (median split along the longest centroid extent, ≤ 4
  /// triangles per leaf). `positions` #N×3, `tris` #F×3.
  TriangleBvh(const Positions& positions, const Triangles& tris);

  /// Recomputes all boxes for moved nodes (same topology). O(F), no allocation.
  void Refit(const Positions& positions);

  /// Closest surface point to `q` no farther than `radius`, or nullopt.
  [[nodiscard]] std::optional<ClosestPointHit> ClosestPoint(const Eigen::Vector3d& q, double radius) const;

  /// First intersection along a→b (smallest t), or nullopt.
  [[nodiscard]] std::optional<SegmentHit> FirstHit(const Eigen::Vector3d& a, const Eigen::Vector3d& b) const;

  /// Every intersection of a→b, unordered; `hits` is cleared first.
  void AllHits(const Eigen::Vector3d& a, const Eigen::Vector3d& b, std::vector<SegmentHit>& hits) const;

  /// Triangles whose bounding box overlaps [lo, hi]; `out` is cleared first.
  void QueryBox(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, std::vector<int32_t>& out) const;

  [[nodiscard]] int32_t num_triangles() const { return static_cast<int32_t>(tris_.rows()); }
  [[nodiscard]] int32_t num_nodes() const { return static_cast<int32_t>(nodes_.size()); }

 private:
  struct Node {
    Eigen::Vector3d lo, hi;  // box, m
    int32_t first = 0;       // leaf: first index into order_; inner: left child (right = first + 1)
    int32_t count = 0;       // leaf: number of triangles; inner: 0
  };
  static constexpr int kLeafSize = 4;
  static constexpr int kMaxDepth = 64;  // the traversal stack is a fixed array

  void BuildRange(int32_t self, int32_t begin, int32_t end, std::vector<Eigen::Vector3d>& centroids, int depth);
  Eigen::Vector3d Corner(int32_t f, int k) const { return positions_.row(tris_(f, k)).transpose(); }

  Triangles tris_;                // #F×3
  Positions positions_;           // #N×3 copy of the last build/refit positions
  std::vector<int32_t> order_;    // #F triangle rows, grouped by leaf
  std::vector<Node> nodes_;       // children always after their parent
};

}  // namespace cutsim::mesh
