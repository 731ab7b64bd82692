#pragma once
/// @file
/// Axis-aligned bounding-box tree over surface triangles: built once,
/// refitted every step in O(F) without allocation, queried by the
/// tool-contact and blade code, and edited locally when a cut changes the
/// surface (`Remove`/`Insert` by triangle id, amortised O(log F)).

#include <array>
#include <cstdint>
#include <span>
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

/// AABB tree over triangles. Triangle ids are the rows of the `tris` given
/// at build; a row whose first index is negative is a dead id (not in the
/// tree). Ids stay stable under Remove/Insert, so a caller can index the
/// tree by its own slot numbers (e.g. CutMesh surface slots).
///
/// Local edits: Remove(id) takes the id out of its leaf in O(1) (boxes stay
/// conservative until the next Refit). Insert(id, tri) of a live id whose
/// new box still fits its leaf's only renames its nodes (a cut re-points a
/// face to a split copy at the same place). Otherwise it climbs by parent
/// links from the id's old leaf, or else from the previous insertion's
/// leaf (a cut inserts the faces of one slit), to the lowest box that holds
/// the triangle, descends from there into the child whose box grows least
/// (enlarging boxes on the way, so the tree is valid at once) and appends
/// to a leaf, which has room for kLeafCapacity ids; a full leaf splits into
/// two new leaves at its median. (From the root every time, an insert cost
/// ~2 000 instructions at 10k tets; from the climb, ~860.)
/// After more insertions than half the live triangles (≥ 64), or a path
/// deeper than the traversal stack allows, the tree is rebuilt from
/// scratch: amortised O(log F) per insertion.
class TriangleBvh {
 public:
  TriangleBvh() = default;
  /// Builds the tree (median split along the longest centroid extent, ≤ 4
  /// triangles per leaf). `positions` #N×3, `tris` #F×3 (rows with a
  /// negative first index are dead ids).
  TriangleBvh(const Positions& positions, const Triangles& tris);

  /// Recomputes all boxes for moved nodes (same topology). O(F), no
  /// allocation once the first `num_rows` rows (−1: all) of `positions` fit
  /// the tree's copy.
  void Refit(const Positions& positions, int32_t num_rows = -1);

  /// Takes triangle `id` out of the tree (no-op for a dead id).
  void Remove(int32_t id);
  /// Puts triangle `id` (any id ≥ 0; the id space grows as needed) with
  /// nodes `tri` into the tree, replacing what `id` held. Reads the three
  /// nodes' rows of `positions`.
  void Insert(int32_t id, const std::array<int32_t, 3>& tri, const Positions& positions);
  /// Whether `id` is in the tree.
  [[nodiscard]] bool alive(int32_t id) const {
    return id >= 0 && id < static_cast<int32_t>(tris_.size()) && tris_[static_cast<size_t>(id)][0] >= 0;
  }
  /// Full rebuilds so far (construction excluded).
  [[nodiscard]] int64_t rebuilds() const { return rebuilds_; }

  // Queries do not depend on the tree's shape, only on the live triangles
  // and positions: lists come sorted by id and ties go to the lowest id. A
  // tree edited by a thousand cuts and one built from scratch over the same
  // surface give the same contact, bit for bit (summation orders included),
  // so the insertion policy can change without changing the physics.

  /// Closest surface point to `q` no farther than `radius`, or nullopt.
  /// Equal distances: the lowest id.
  [[nodiscard]] std::optional<ClosestPointHit> ClosestPoint(const Eigen::Vector3d& q, double radius) const;

  /// First intersection along a→b (smallest t, then the lowest id), or nullopt.
  [[nodiscard]] std::optional<SegmentHit> FirstHit(const Eigen::Vector3d& a, const Eigen::Vector3d& b) const;

  /// Every intersection of a→b, sorted by triangle id; `hits` is cleared first.
  void AllHits(const Eigen::Vector3d& a, const Eigen::Vector3d& b, std::vector<SegmentHit>& hits) const;

  /// Triangles whose bounding box overlaps [lo, hi], sorted by id; `out` is
  /// cleared first.
  void QueryBox(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, std::vector<int32_t>& out) const;

  /// Size of the id space (live and dead ids).
  [[nodiscard]] int32_t num_triangles() const { return static_cast<int32_t>(tris_.size()); }
  [[nodiscard]] int32_t num_live_triangles() const { return num_live_; }
  [[nodiscard]] int32_t num_nodes() const { return static_cast<int32_t>(nodes_.size()); }

 private:
  struct Node {
    Eigen::Vector3d lo, hi;  // box, m (empty: lo > hi)
    int32_t first = 0;       // leaf: first index into order_; inner: left child (right = first + 1)
    int32_t count = 0;       // leaf: number of triangles (≥ 0); inner: −1
  };
  static constexpr int kLeafSize = 4;      // at build
  static constexpr int kLeafCapacity = 8;  // room in order_ per leaf, for inserts
  static constexpr int kMaxDepth = 64;     // the traversal stack is a fixed array

  void Build();
  void BuildRange(int32_t self, int32_t begin, int32_t end, std::vector<int32_t>& ids,
                  const std::vector<Eigen::Vector3d>& centroids, int depth);
  int32_t NewLeaf(std::span<const int32_t> ids, int32_t parent);
  void LeafBox(Node& n) const;
  Eigen::Vector3d Corner(int32_t f, int k) const {
    return positions_.row(tris_[static_cast<size_t>(f)][static_cast<size_t>(k)]).transpose();
  }

  std::vector<std::array<int32_t, 3>> tris_;  // #ids; [0] < 0: dead
  Positions positions_;           // #N×3 copy of the last build/refit positions
  std::vector<int32_t> order_;    // kLeafCapacity entries per leaf, the first `count` used
  std::vector<Node> nodes_;       // children always after their parent
  std::vector<int32_t> parent_;   // #nodes: parent node (−1: the root)
  int32_t last_leaf_ = -1;        // leaf of the last insertion (−1: none since the build)
  std::vector<int32_t> leaf_of_;  // #ids: leaf node holding the id (−1: none)
  std::vector<int32_t> pos_of_;   // #ids: index in order_
  int32_t num_live_ = 0;
  int32_t inserted_since_build_ = 0;
  int64_t rebuilds_ = 0;
};

}  // namespace cutsim::mesh
