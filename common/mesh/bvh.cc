#include "common/mesh/bvh.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "common/core/error.h"

namespace cutsim::mesh {

using Eigen::Vector3d;

ClosestPointHit ClosestPointOnTriangle(const Vector3d& q, const Vector3d& p0, const Vector3d& p1,
                                       const Vector3d& p2) {
  ClosestPointHit hit;
  auto done = [&](double w0, double w1, double w2) {
    hit.bary = Vector3d(w0, w1, w2);
    hit.point = w0 * p0 + w1 * p1 + w2 * p2;
    hit.distance = (hit.point - q).norm();
    return hit;
  };
  const Vector3d ab = p1 - p0, ac = p2 - p0, ap = q - p0;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0.0 && d2 <= 0.0) return done(1, 0, 0);
  const Vector3d bp = q - p1;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0.0 && d4 <= d3) return done(0, 1, 0);
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
    const double v = d1 / (d1 - d3);
    return done(1 - v, v, 0);
  }
  const Vector3d cp = q - p2;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0.0 && d5 <= d6) return done(0, 0, 1);
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
    const double w = d2 / (d2 - d6);
    return done(1 - w, 0, w);
  }
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
    const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return done(0, 1 - w, w);
  }
  const double sum = va + vb + vc;
  if (!(sum > 0.0)) return done(1, 0, 0);  // degenerate triangle: every region test failed
  const double v = vb / sum, w = vc / sum;
  return done(1 - v - w, v, w);
}

std::optional<SegmentHit> IntersectSegmentTriangle(const Vector3d& a, const Vector3d& b, const Vector3d& p0,
                                                   const Vector3d& p1, const Vector3d& p2) {
  const Vector3d dir = b - a, e1 = p1 - p0, e2 = p2 - p0;
  const Vector3d pv = dir.cross(e2);
  const double det = e1.dot(pv);
  // Parallel (or degenerate) relative to the triangle's size and the segment length.
  if (std::abs(det) <= 1e-14 * e1.norm() * e2.norm() * dir.norm()) return std::nullopt;
  const double inv = 1.0 / det;
  const Vector3d tv = a - p0;
  const double u = tv.dot(pv) * inv;
  if (u < 0.0 || u > 1.0) return std::nullopt;
  const Vector3d qv = tv.cross(e1);
  const double v = dir.dot(qv) * inv;
  if (v < 0.0 || u + v > 1.0) return std::nullopt;
  const double t = e2.dot(qv) * inv;
  if (t < 0.0 || t > 1.0) return std::nullopt;
  SegmentHit hit;
  hit.t = t;
  hit.point = a + t * dir;
  hit.bary = Vector3d(1.0 - u - v, u, v);
  return hit;
}

namespace {

// Distance² from q to the box [lo, hi].
double BoxDistance2(const Vector3d& q, const Vector3d& lo, const Vector3d& hi) {
  return (lo - q).cwiseMax(q - hi).cwiseMax(0.0).squaredNorm();
}

// Box culling never drops a triangle its own exact test would keep: a box
// test rounds differently from the triangle test (a closest point on a
// box face, a segment through a box corner), and which triangles share a
// box depends on the tree's shape. So boxes are culled with a relative
// slack, and only the triangle tests decide: answers that do not depend on
// the tree (bvh.h).
constexpr double kCullSlack = 1e-9;

// Slab test of the segment a + t·dir, t ∈ [0, t_max], against the box.
bool SegmentHitsBox(const Vector3d& a, const Vector3d& inv_dir, double t_max, const Vector3d& lo,
                    const Vector3d& hi) {
  double t0 = 0.0, t1 = t_max;
  for (int k = 0; k < 3; ++k) {
    double ta = (lo[k] - a[k]) * inv_dir[k], tb = (hi[k] - a[k]) * inv_dir[k];
    if (std::isnan(ta) || std::isnan(tb)) {  // 0·inf: the segment lies in the slab's plane
      if (a[k] < lo[k] || a[k] > hi[k]) return false;
      continue;
    }
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
    if (t0 > t1 + kCullSlack) return false;
  }
  return true;
}

}  // namespace

TriangleBvh::TriangleBvh(const Positions& positions, const Triangles& tris) : positions_(positions) {
  tris_.resize(static_cast<size_t>(tris.rows()));
  for (int32_t f = 0; f < tris.rows(); ++f) tris_[static_cast<size_t>(f)] = {tris(f, 0), tris(f, 1), tris(f, 2)};
  Build();
  rebuilds_ = 0;
}

void TriangleBvh::Build() {
  ++rebuilds_;
  inserted_since_build_ = 0;
  nodes_.clear();
  parent_.clear();
  last_leaf_ = -1;
  order_.clear();
  leaf_of_.assign(tris_.size(), -1);
  pos_of_.assign(tris_.size(), -1);
  std::vector<int32_t> ids;
  ids.reserve(tris_.size());
  std::vector<Vector3d> centroids(tris_.size(), Vector3d::Zero());
  for (size_t f = 0; f < tris_.size(); ++f) {
    if (tris_[f][0] < 0) continue;
    ids.push_back(static_cast<int32_t>(f));
    const auto i = static_cast<int32_t>(f);
    centroids[f] = (Corner(i, 0) + Corner(i, 1) + Corner(i, 2)) / 3.0;
  }
  num_live_ = static_cast<int32_t>(ids.size());
  if (ids.empty()) return;
  const size_t leaves = ids.size() / kLeafSize + 2;
  nodes_.reserve(2 * leaves);
  parent_.reserve(2 * leaves);
  order_.reserve(kLeafCapacity * leaves);
  nodes_.emplace_back();
  parent_.push_back(-1);
  BuildRange(0, 0, num_live_, ids, centroids, 0);
  Refit(positions_);
}

int32_t TriangleBvh::NewLeaf(std::span<const int32_t> ids, int32_t parent) {
  const auto first = static_cast<int32_t>(order_.size());
  order_.resize(order_.size() + kLeafCapacity, -1);
  const auto self = static_cast<int32_t>(nodes_.size());
  nodes_.emplace_back();
  parent_.push_back(parent);
  for (size_t k = 0; k < ids.size(); ++k) {
    order_[static_cast<size_t>(first) + k] = ids[k];
    leaf_of_[static_cast<size_t>(ids[k])] = self;
    pos_of_[static_cast<size_t>(ids[k])] = first + static_cast<int32_t>(k);
  }
  nodes_.back().first = first;
  nodes_.back().count = static_cast<int32_t>(ids.size());
  return self;
}

void TriangleBvh::BuildRange(int32_t self, int32_t begin, int32_t end, std::vector<int32_t>& ids,
                             const std::vector<Vector3d>& centroids, int depth) {
  if (end - begin <= kLeafSize || depth >= kMaxDepth - 2) {
    // Leaves are created in place of `self`: move the node's slot to a leaf.
    const auto first = static_cast<int32_t>(order_.size());
    order_.resize(order_.size() + static_cast<size_t>(std::max<int32_t>(kLeafCapacity, end - begin)), -1);
    for (int32_t i = begin; i < end; ++i) {
      const int32_t id = ids[static_cast<size_t>(i)];
      order_[static_cast<size_t>(first + i - begin)] = id;
      leaf_of_[static_cast<size_t>(id)] = self;
      pos_of_[static_cast<size_t>(id)] = first + i - begin;
    }
    nodes_[static_cast<size_t>(self)].first = first;
    nodes_[static_cast<size_t>(self)].count = end - begin;
    return;
  }
  Vector3d lo = Vector3d::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (int32_t i = begin; i < end; ++i) {
    const auto& c = centroids[static_cast<size_t>(ids[static_cast<size_t>(i)])];
    lo = lo.cwiseMin(c);
    hi = hi.cwiseMax(c);
  }
  int axis = 0;
  (hi - lo).maxCoeff(&axis);
  const int32_t mid = begin + (end - begin) / 2;
  std::nth_element(ids.begin() + begin, ids.begin() + mid, ids.begin() + end,
                   [&](int32_t x, int32_t y) {
                     return centroids[static_cast<size_t>(x)][axis] < centroids[static_cast<size_t>(y)][axis];
                   });
  const auto left = static_cast<int32_t>(nodes_.size());
  nodes_[static_cast<size_t>(self)].first = left;
  nodes_[static_cast<size_t>(self)].count = -1;
  nodes_.emplace_back();  // children are allocated together, after their parent
  nodes_.emplace_back();
  parent_.push_back(self);
  parent_.push_back(self);
  BuildRange(left, begin, mid, ids, centroids, depth + 1);
  BuildRange(left + 1, mid, end, ids, centroids, depth + 1);
}

void TriangleBvh::LeafBox(Node& n) const {
  n.lo = Vector3d::Constant(std::numeric_limits<double>::infinity());
  n.hi = -n.lo;
  for (int32_t k = n.first; k < n.first + n.count; ++k) {
    const int32_t f = order_[static_cast<size_t>(k)];
    for (int c = 0; c < 3; ++c) {
      n.lo = n.lo.cwiseMin(Corner(f, c));
      n.hi = n.hi.cwiseMax(Corner(f, c));
    }
  }
}

void TriangleBvh::Refit(const Positions& positions, int32_t num_rows) {
  const Eigen::Index rows = num_rows < 0 ? positions.rows() : num_rows;
  if (positions_.rows() < rows) positions_.resize(std::max<Eigen::Index>(rows, positions.rows()), 3);
  positions_.topRows(rows) = positions.topRows(rows);  // no allocation once sized
  // Children come after parents, so a reverse sweep sees children first.
  for (auto i = static_cast<int64_t>(nodes_.size()) - 1; i >= 0; --i) {
    Node& n = nodes_[static_cast<size_t>(i)];
    if (n.count >= 0) {
      LeafBox(n);
    } else {
      const Node& l = nodes_[static_cast<size_t>(n.first)];
      const Node& r = nodes_[static_cast<size_t>(n.first) + 1];
      n.lo = l.lo.cwiseMin(r.lo);
      n.hi = l.hi.cwiseMax(r.hi);
    }
  }
}

void TriangleBvh::Remove(int32_t id) {
  if (!alive(id)) return;
  const auto i = static_cast<size_t>(id);
  const int32_t leaf = leaf_of_[i];
  Node& n = nodes_[static_cast<size_t>(leaf)];
  const int32_t last = n.first + n.count - 1;
  const int32_t moved = order_[static_cast<size_t>(last)];
  order_[static_cast<size_t>(pos_of_[i])] = moved;
  pos_of_[static_cast<size_t>(moved)] = pos_of_[i];
  order_[static_cast<size_t>(last)] = -1;
  --n.count;
  leaf_of_[i] = -1;
  pos_of_[i] = -1;
  tris_[i][0] = -1;
  --num_live_;
}

void TriangleBvh::Insert(int32_t id, const std::array<int32_t, 3>& tri, const Positions& positions) {
  CUTSIM_CHECK(id >= 0 && tri[0] >= 0 && tri[1] >= 0 && tri[2] >= 0, "TriangleBvh::Insert: bad id or node");
  const auto i = static_cast<size_t>(id);
  const bool was_alive = alive(id);
  if (i >= tris_.size()) {
    tris_.resize(i + 1, {-1, -1, -1});
    leaf_of_.resize(i + 1, -1);
    pos_of_.resize(i + 1, -1);
  }
  const int32_t max_node = std::max({tri[0], tri[1], tri[2]});
  if (positions_.rows() <= max_node) {
    Positions grown(std::max<Eigen::Index>(positions.rows(), max_node + 1), 3);
    grown.topRows(positions_.rows()) = positions_;
    positions_ = std::move(grown);
  }
  for (const int32_t v : tri) positions_.row(v) = positions.row(v);
  auto corner = [&](int k) -> Vector3d { return positions_.row(tri[static_cast<size_t>(k)]).transpose(); };
  const Vector3d lo = corner(0).cwiseMin(corner(1)).cwiseMin(corner(2));
  const Vector3d hi = corner(0).cwiseMax(corner(1)).cwiseMax(corner(2));
  auto holds = [&](int32_t node) {
    const Node& n = nodes_[static_cast<size_t>(node)];
    return (n.lo.array() <= lo.array()).all() && (hi.array() <= n.hi.array()).all();
  };
  // Where to start: the id's own leaf if it is re-inserted (a cut re-points
  // a surface face to a split copy, in place: same box), else the leaf the
  // previous insertion went to (a cut inserts the faces of one slit).
  int32_t start = last_leaf_;
  if (was_alive) {
    start = leaf_of_[i];
    if (holds(start)) {  // still fits its leaf: the tree is unchanged
      tris_[i] = tri;
      last_leaf_ = start;
      return;
    }
    Remove(id);
  }
  tris_[i] = tri;
  ++num_live_;
  ++inserted_since_build_;
  if (nodes_.empty() || inserted_since_build_ > std::max(64, num_live_ / 2)) {
    Build();  // amortised: paid by the insertions since the last build
    return;
  }
  const Vector3d centre = 0.5 * (lo + hi);
  auto area = [](const Vector3d& l, const Vector3d& h) {
    const Vector3d e = (h - l).cwiseMax(0.0);
    return e.x() * e.y() + e.y() * e.z() + e.z() * e.x();
  };
  // Descend from the lowest ancestor of `start` whose box holds the
  // triangle (the root at worst): above it every box already holds it, and
  // a cut's faces share a subtree a few levels up, so the descent is short
  // instead of the tree's whole depth. `depth`: the start's depth, for the
  // traversal stack's limit.
  int32_t at = 0;
  int depth = 0;
  if (start >= 0) {
    int32_t found = -1;
    for (int32_t a = start; a >= 0; a = parent_[static_cast<size_t>(a)]) {
      if (found >= 0) {
        ++depth;
      } else if (holds(a)) {
        found = a;
      }
    }
    if (found >= 0) at = found;
    else depth = 0;
  }
  while (true) {
    Node& n = nodes_[static_cast<size_t>(at)];
    const bool empty = !(n.lo.x() <= n.hi.x());
    n.lo = empty ? lo : n.lo.cwiseMin(lo);
    n.hi = empty ? hi : n.hi.cwiseMax(hi);
    if (n.count >= 0) break;
    // Least growth of the surface area; ties (e.g. both contain it) by distance to the box centre.
    double best_growth = std::numeric_limits<double>::infinity();
    double best_distance = best_growth;
    int32_t pick = n.first;
    for (int32_t c = n.first; c <= n.first + 1; ++c) {
      const Node& ch = nodes_[static_cast<size_t>(c)];
      const bool ch_empty = !(ch.lo.x() <= ch.hi.x());
      const double growth =
          ch_empty ? area(lo, hi) : area(ch.lo.cwiseMin(lo), ch.hi.cwiseMax(hi)) - area(ch.lo, ch.hi);
      const double distance = ch_empty ? best_distance : (0.5 * (ch.lo + ch.hi) - centre).squaredNorm();
      if (growth < best_growth || (growth == best_growth && distance < best_distance)) {
        best_growth = growth;
        best_distance = distance;
        pick = c;
      }
    }
    CUTSIM_CHECK(pick > at, "TriangleBvh::Insert: children must follow their parent");
    at = pick;
    if (++depth >= kMaxDepth - 2) {  // too deep for the traversal stack: rebuild (rare)
      Build();
      return;
    }
  }
  Node& leaf = nodes_[static_cast<size_t>(at)];
  if (leaf.count < kLeafCapacity) {
    const int32_t p = leaf.first + leaf.count++;
    order_[static_cast<size_t>(p)] = id;
    leaf_of_[i] = at;
    pos_of_[i] = p;
    last_leaf_ = at;
    return;
  }
  if (leaf.count > kLeafCapacity || depth + 2 >= kMaxDepth - 1) {
    Build();
    return;
  }
  // Split the full leaf: its ids and the new one, halved at the median
  // along the longest centroid extent, into two new leaves.
  std::array<int32_t, kLeafCapacity + 1> ids{};
  for (int k = 0; k < kLeafCapacity; ++k) ids[static_cast<size_t>(k)] = order_[static_cast<size_t>(leaf.first + k)];
  ids[kLeafCapacity] = id;
  std::array<Vector3d, kLeafCapacity + 1> centroids;  // once each, not per comparison
  Vector3d clo = Vector3d::Constant(std::numeric_limits<double>::infinity()), chi = -clo;
  for (size_t k = 0; k < ids.size(); ++k) {
    centroids[k] = (Corner(ids[k], 0) + Corner(ids[k], 1) + Corner(ids[k], 2)) / 3.0;
    clo = clo.cwiseMin(centroids[k]);
    chi = chi.cwiseMax(centroids[k]);
  }
  int axis = 0;
  (chi - clo).maxCoeff(&axis);
  std::array<std::pair<double, int32_t>, kLeafCapacity + 1> keyed;
  for (size_t k = 0; k < ids.size(); ++k) keyed[k] = {centroids[k][axis], ids[k]};
  constexpr size_t kMid = (kLeafCapacity + 1) / 2;
  std::nth_element(keyed.begin(), keyed.begin() + kMid, keyed.end());
  for (size_t k = 0; k < ids.size(); ++k) ids[k] = keyed[k].second;
  // The old leaf's order_ segment is abandoned (reclaimed at the next build).
  const int32_t left = NewLeaf(std::span<const int32_t>(ids.data(), kMid), at);
  const int32_t right = NewLeaf(std::span<const int32_t>(ids.data() + kMid, ids.size() - kMid), at);
  CUTSIM_CHECK(right == left + 1, "TriangleBvh: children must be adjacent");
  LeafBox(nodes_[static_cast<size_t>(left)]);
  LeafBox(nodes_[static_cast<size_t>(right)]);
  Node& parent = nodes_[static_cast<size_t>(at)];  // nodes_ may have moved
  parent.first = left;
  parent.count = -1;
  last_leaf_ = leaf_of_[i];
}

std::optional<ClosestPointHit> TriangleBvh::ClosestPoint(const Vector3d& q, double radius) const {
  std::optional<ClosestPointHit> best;
  if (nodes_.empty() || !(radius >= 0.0)) return best;
  double best_d2 = radius * radius;
  std::array<int32_t, 2 * kMaxDepth> stack{};
  int top = 0;
  stack[static_cast<size_t>(top++)] = 0;
  while (top > 0) {
    const Node& n = nodes_[static_cast<size_t>(stack[static_cast<size_t>(--top)])];
    if (BoxDistance2(q, n.lo, n.hi) > best_d2 * (1.0 + kCullSlack)) continue;
    if (n.count >= 0) {
      for (int32_t k = n.first; k < n.first + n.count; ++k) {
        const int32_t f = order_[static_cast<size_t>(k)];
        ClosestPointHit hit = ClosestPointOnTriangle(q, Corner(f, 0), Corner(f, 1), Corner(f, 2));
        const double d2 = hit.distance * hit.distance;
        if (d2 < best_d2 || (d2 == best_d2 && (!best || f < best->tri))) {
          best_d2 = d2;
          hit.tri = f;
          best = hit;
        }
      }
      continue;
    }
    // Visit the nearer child first (pushed last).
    const int32_t l = n.first, r = n.first + 1;
    const double dl = BoxDistance2(q, nodes_[static_cast<size_t>(l)].lo, nodes_[static_cast<size_t>(l)].hi);
    const double dr = BoxDistance2(q, nodes_[static_cast<size_t>(r)].lo, nodes_[static_cast<size_t>(r)].hi);
    stack[static_cast<size_t>(top++)] = dl < dr ? r : l;
    stack[static_cast<size_t>(top++)] = dl < dr ? l : r;
  }
  return best;
}

template <typename Visit>
static void ForEachSegmentCandidate(const std::vector<int32_t>& order, const auto& nodes, const Vector3d& a,
                                    const Vector3d& b, Visit&& visit) {
  if (nodes.empty()) return;
  const Vector3d dir = b - a;
  const Vector3d inv_dir = dir.cwiseInverse();
  std::array<int32_t, 128> stack{};
  int top = 0;
  stack[static_cast<size_t>(top++)] = 0;
  while (top > 0) {
    const auto& n = nodes[static_cast<size_t>(stack[static_cast<size_t>(--top)])];
    if (!(n.lo.x() <= n.hi.x()) || !SegmentHitsBox(a, inv_dir, 1.0, n.lo, n.hi)) continue;  // empty box
    if (n.count >= 0) {
      for (int32_t k = n.first; k < n.first + n.count; ++k) visit(order[static_cast<size_t>(k)]);
    } else {
      stack[static_cast<size_t>(top++)] = n.first;
      stack[static_cast<size_t>(top++)] = n.first + 1;
    }
  }
}

std::optional<SegmentHit> TriangleBvh::FirstHit(const Vector3d& a, const Vector3d& b) const {
  std::optional<SegmentHit> best;
  ForEachSegmentCandidate(order_, nodes_, a, b, [&](int32_t f) {
    auto hit = IntersectSegmentTriangle(a, b, Corner(f, 0), Corner(f, 1), Corner(f, 2));
    if (hit && (!best || hit->t < best->t || (hit->t == best->t && f < best->tri))) {
      hit->tri = f;
      best = hit;
    }
  });
  return best;
}

void TriangleBvh::AllHits(const Vector3d& a, const Vector3d& b, std::vector<SegmentHit>& hits) const {
  hits.clear();
  ForEachSegmentCandidate(order_, nodes_, a, b, [&](int32_t f) {
    if (auto hit = IntersectSegmentTriangle(a, b, Corner(f, 0), Corner(f, 1), Corner(f, 2))) {
      hit->tri = f;
      hits.push_back(*hit);
    }
  });
  std::sort(hits.begin(), hits.end(), [](const SegmentHit& x, const SegmentHit& y) { return x.tri < y.tri; });
}

void TriangleBvh::QueryBox(const Vector3d& lo, const Vector3d& hi, std::vector<int32_t>& out) const {
  out.clear();
  if (nodes_.empty()) return;
  auto overlaps = [&](const Vector3d& l, const Vector3d& h) {
    return (l.array() <= hi.array()).all() && (lo.array() <= h.array()).all();
  };
  std::array<int32_t, 2 * kMaxDepth> stack{};
  int top = 0;
  stack[static_cast<size_t>(top++)] = 0;
  while (top > 0) {
    const Node& n = nodes_[static_cast<size_t>(stack[static_cast<size_t>(--top)])];
    if (!overlaps(n.lo, n.hi)) continue;
    if (n.count >= 0) {
      for (int32_t k = n.first; k < n.first + n.count; ++k) {
        const int32_t f = order_[static_cast<size_t>(k)];
        const Vector3d tl = Corner(f, 0).cwiseMin(Corner(f, 1)).cwiseMin(Corner(f, 2));
        const Vector3d th = Corner(f, 0).cwiseMax(Corner(f, 1)).cwiseMax(Corner(f, 2));
        if (overlaps(tl, th)) out.push_back(f);
      }
    } else {
      stack[static_cast<size_t>(top++)] = n.first;
      stack[static_cast<size_t>(top++)] = n.first + 1;
    }
  }
  std::sort(out.begin(), out.end());
}

}  // namespace cutsim::mesh
