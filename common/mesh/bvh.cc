#include "common/mesh/bvh.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

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
    if (t0 > t1) return false;
  }
  return true;
}

}  // namespace

TriangleBvh::TriangleBvh(const Positions& positions, const Triangles& tris)
    : tris_(tris), positions_(positions) {
  const auto num_tris = static_cast<int32_t>(tris.rows());
  order_.resize(static_cast<size_t>(num_tris));
  std::vector<Vector3d> centroids(static_cast<size_t>(num_tris));
  for (int32_t f = 0; f < num_tris; ++f) {
    order_[static_cast<size_t>(f)] = f;
    centroids[static_cast<size_t>(f)] = (Corner(f, 0) + Corner(f, 1) + Corner(f, 2)) / 3.0;
  }
  if (num_tris == 0) return;
  nodes_.reserve(static_cast<size_t>(2 * (num_tris / kLeafSize + 1)));
  nodes_.emplace_back();
  BuildRange(0, 0, num_tris, centroids, 0);
  Refit(positions);
}

void TriangleBvh::BuildRange(int32_t self, int32_t begin, int32_t end, std::vector<Vector3d>& centroids,
                             int depth) {
  if (end - begin <= kLeafSize || depth >= kMaxDepth - 1) {
    nodes_[static_cast<size_t>(self)].first = begin;
    nodes_[static_cast<size_t>(self)].count = end - begin;
    return;
  }
  Vector3d lo = Vector3d::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (int32_t i = begin; i < end; ++i) {
    const auto& c = centroids[static_cast<size_t>(order_[static_cast<size_t>(i)])];
    lo = lo.cwiseMin(c);
    hi = hi.cwiseMax(c);
  }
  int axis = 0;
  (hi - lo).maxCoeff(&axis);
  const int32_t mid = begin + (end - begin) / 2;
  std::nth_element(order_.begin() + begin, order_.begin() + mid, order_.begin() + end,
                   [&](int32_t x, int32_t y) {
                     return centroids[static_cast<size_t>(x)][axis] < centroids[static_cast<size_t>(y)][axis];
                   });
  const auto left = static_cast<int32_t>(nodes_.size());
  nodes_[static_cast<size_t>(self)].first = left;
  nodes_[static_cast<size_t>(self)].count = 0;
  nodes_.emplace_back();  // children are allocated together, after their parent
  nodes_.emplace_back();
  BuildRange(left, begin, mid, centroids, depth + 1);
  BuildRange(left + 1, mid, end, centroids, depth + 1);
}

void TriangleBvh::Refit(const Positions& positions) {
  positions_ = positions;  // same size: Eigen reuses the storage
  // Children come after parents, so a reverse sweep sees children first.
  for (auto i = static_cast<int64_t>(nodes_.size()) - 1; i >= 0; --i) {
    Node& n = nodes_[static_cast<size_t>(i)];
    if (n.count > 0) {
      n.lo = Vector3d::Constant(std::numeric_limits<double>::infinity());
      n.hi = -n.lo;
      for (int32_t k = n.first; k < n.first + n.count; ++k) {
        const int32_t f = order_[static_cast<size_t>(k)];
        for (int c = 0; c < 3; ++c) {
          n.lo = n.lo.cwiseMin(Corner(f, c));
          n.hi = n.hi.cwiseMax(Corner(f, c));
        }
      }
    } else {
      const Node& l = nodes_[static_cast<size_t>(n.first)];
      const Node& r = nodes_[static_cast<size_t>(n.first) + 1];
      n.lo = l.lo.cwiseMin(r.lo);
      n.hi = l.hi.cwiseMax(r.hi);
    }
  }
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
    if (BoxDistance2(q, n.lo, n.hi) > best_d2) continue;
    if (n.count > 0) {
      for (int32_t k = n.first; k < n.first + n.count; ++k) {
        const int32_t f = order_[static_cast<size_t>(k)];
        ClosestPointHit hit = ClosestPointOnTriangle(q, Corner(f, 0), Corner(f, 1), Corner(f, 2));
        if (hit.distance * hit.distance <= best_d2) {
          best_d2 = hit.distance * hit.distance;
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
    if (!SegmentHitsBox(a, inv_dir, 1.0, n.lo, n.hi)) continue;
    if (n.count > 0) {
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
    if (hit && (!best || hit->t < best->t)) {
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
    if (n.count > 0) {
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
}

}  // namespace cutsim::mesh
