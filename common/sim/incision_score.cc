#include "common/sim/incision_score.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Dense>

#include "cutsim/v1/metrics.pb.h"

namespace cutsim::sim {

IncisionScorer::IncisionScorer(PlannedIncision plan) : plan_(std::move(plan)) {
  for (size_t i = 1; i < plan_.points.size(); ++i) length_ += (plan_.points[i] - plan_.points[i - 1]).norm();
  in_tissue_.assign(static_cast<size_t>(kArcCells) * kDepthCells, 1);
  cells_in_tissue_ = static_cast<int64_t>(in_tissue_.size());
}

Eigen::Vector3d IncisionScorer::PointAt(double arc) const {
  for (size_t i = 1; i < plan_.points.size(); ++i) {
    const Eigen::Vector3d& a = plan_.points[i - 1];
    const Eigen::Vector3d& b = plan_.points[i];
    const double len = (b - a).norm();
    if (arc <= len || i + 1 == plan_.points.size()) return len > 0.0 ? a + std::min(arc / len, 1.0) * (b - a) : a;
    arc -= len;
  }
  return plan_.points.back();
}

namespace {

/// Whether p lies in the tet a, b, c, d (boundary included, with a
/// round-off margin).
bool InTet(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
           const Eigen::Vector3d& d) {
  Eigen::Matrix3d m;
  m << b - a, c - a, d - a;
  const double det = m.determinant();
  if (!(std::abs(det) > 0.0)) return false;
  const Eigen::Vector3d w = m.inverse() * (p - a);
  constexpr double kMargin = -1e-9;
  return w.minCoeff() >= kMargin && 1.0 - w.sum() >= kMargin;
}

}  // namespace

void IncisionScorer::SetTissue(const mesh::TetMesh& rest) {
  const auto node = [&rest](int32_t n) -> Eigen::Vector3d { return rest.nodes.row(n).transpose(); };
  std::vector<Eigen::Vector3d> centres;
  centres.reserve(in_tissue_.size());
  for (int i = 0; i < kArcCells; ++i) {
    const Eigen::Vector3d on_plan = PointAt((i + 0.5) * length_ / kArcCells);
    for (int j = 0; j < kDepthCells; ++j) centres.push_back(on_plan - (j + 0.5) * plan_.depth / kDepthCells * plan_.normal);
  }
  std::fill(in_tissue_.begin(), in_tissue_.end(), uint8_t{0});
  for (int32_t t = 0; t < rest.num_tets(); ++t) {
    const Eigen::Vector3d a = node(rest.tets(t, 0)), b = node(rest.tets(t, 1)), c = node(rest.tets(t, 2)),
                          d = node(rest.tets(t, 3));
    const Eigen::Vector3d lo = a.cwiseMin(b).cwiseMin(c).cwiseMin(d), hi = a.cwiseMax(b).cwiseMax(c).cwiseMax(d);
    for (size_t k = 0; k < centres.size(); ++k) {
      const Eigen::Vector3d& p = centres[k];
      if (in_tissue_[k] || (p.array() < lo.array()).any() || (p.array() > hi.array()).any()) continue;
      if (InTet(p, a, b, c, d)) in_tissue_[k] = 1;
    }
  }
  cells_in_tissue_ = std::count(in_tissue_.begin(), in_tissue_.end(), uint8_t{1});
}

void IncisionScorer::CoverCells(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                                std::vector<uint8_t>& covered) const {
  // (arc, depth) of each corner, in cell units.
  Eigen::Vector2d q[3];
  const Eigen::Vector3d* corners[3] = {&a, &b, &c};
  const double arc_cell = length_ / kArcCells, depth_cell = plan_.depth / kDepthCells;
  for (int k = 0; k < 3; ++k) {
    const Nearest n = NearestOnPlan(*corners[k]);
    q[k] = {n.arc / arc_cell, (n.point - *corners[k]).dot(plan_.normal) / depth_cell};
  }
  const double area2 = (q[1] - q[0]).x() * (q[2] - q[0]).y() - (q[1] - q[0]).y() * (q[2] - q[0]).x();
  if (!(std::abs(area2) > 1e-12)) return;  // edge-on to the plan: covers nothing
  const Eigen::Vector2d lo = q[0].cwiseMin(q[1]).cwiseMin(q[2]), hi = q[0].cwiseMax(q[1]).cwiseMax(q[2]);
  const int i0 = std::max(0, static_cast<int>(std::floor(lo.x() - 0.5)));
  const int i1 = std::min(kArcCells - 1, static_cast<int>(std::ceil(hi.x() - 0.5)));
  const int j0 = std::max(0, static_cast<int>(std::floor(lo.y() - 0.5)));
  const int j1 = std::min(kDepthCells - 1, static_cast<int>(std::ceil(hi.y() - 0.5)));
  // Barycentric test with a small margin so that cells on an edge shared by
  // two faces are not lost to round-off.
  constexpr double kMargin = -1e-9;
  for (int i = i0; i <= i1; ++i) {
    for (int j = j0; j <= j1; ++j) {
      const Eigen::Vector2d p(i + 0.5, j + 0.5);
      const auto edge = [&p](const Eigen::Vector2d& u, const Eigen::Vector2d& v) {
        return (v - u).x() * (p - u).y() - (v - u).y() * (p - u).x();
      };
      const double w0 = edge(q[1], q[2]) / area2, w1 = edge(q[2], q[0]) / area2, w2 = edge(q[0], q[1]) / area2;
      if (w0 >= kMargin && w1 >= kMargin && w2 >= kMargin) covered[static_cast<size_t>(i * kDepthCells + j)] = 1;
    }
  }
}

IncisionScorer::Nearest IncisionScorer::NearestOnPlan(const Eigen::Vector3d& p) const {
  // Across the surface: every vector loses its component along the normal.
  const Eigen::Vector3d& n = plan_.normal;
  const auto across = [&n](const Eigen::Vector3d& v) -> Eigen::Vector3d { return v - v.dot(n) * n; };
  const Eigen::Vector3d pp = across(p);
  Nearest best{.point = plan_.points.front(), .distance = std::numeric_limits<double>::infinity(), .arc = 0.0};
  double arc = 0.0;
  for (size_t i = 1; i < plan_.points.size(); ++i) {
    const Eigen::Vector3d& a = plan_.points[i - 1];
    const Eigen::Vector3d& b = plan_.points[i];
    const Eigen::Vector3d ab = across(b - a);
    const double len2 = ab.squaredNorm();
    const double s = len2 > 0.0 ? std::clamp((pp - across(a)).dot(ab) / len2, 0.0, 1.0) : 0.0;
    const double d = (pp - across(a) - s * ab).norm();
    if (d < best.distance) best = {.point = a + s * (b - a), .distance = d, .arc = arc + s * (b - a).norm()};
    arc += (b - a).norm();
  }
  return best;
}

double IncisionScorer::Deviation(const Eigen::Vector3d& rest_point) const {
  return NearestOnPlan(rest_point).distance;
}

void IncisionScorer::AddCutPoint(double t, const Eigen::Vector3d& rest_point) {
  const double d = Deviation(rest_point);
  ++count_;
  sum_deviation_ += d;
  max_deviation_ = std::max(max_deviation_, d);
  if (kept_.size() < kMaxKeptCutPoints) kept_.push_back({.t = t, .rest = rest_point, .deviation = d});
}

void IncisionScorer::Restore(std::span<const CutPoint> points) {
  kept_.clear();
  count_ = 0;
  sum_deviation_ = max_deviation_ = 0.0;
  for (const CutPoint& c : points) AddCutPoint(c.t, c.rest);
}

template <typename T>
IncisionScore IncisionScorer::Score(const T* rest, const mesh::Triangles& surface, std::span<const uint8_t> opened,
                                    const SessionMetrics& metrics, double sim_time) const {
  IncisionScore s;
  s.set_cut_points(static_cast<double>(count_));
  s.set_mean_deviation(count_ > 0 ? sum_deviation_ / static_cast<double>(count_) : 0.0);
  s.set_max_deviation(max_deviation_);
  s.set_cut_off_volume(metrics.cut_off_volume());
  s.set_max_stress_outside(metrics.max_stress_outside());
  s.set_peak_force(metrics.peak_force());
  s.set_mean_force(metrics.mean_force());
  s.set_contact_time(metrics.contact_time());
  s.set_duration(sim_time);

  const auto at = [rest](int32_t v) {
    return Eigen::Vector3d(static_cast<double>(rest[3 * v]), static_cast<double>(rest[3 * v + 1]),
                           static_cast<double>(rest[3 * v + 2]));
  };
  const double tol = plan_.tolerance;
  std::vector<uint8_t> covered(in_tissue_.size(), 0);
  double opened_area_outside = 0.0;
  double depth_reached = 0.0;
  const auto slots = std::min(static_cast<size_t>(surface.rows()), opened.size());
  for (size_t f = 0; f < slots; ++f) {
    const auto r = static_cast<Eigen::Index>(f);
    if (!opened[f] || surface(r, 0) < 0) continue;
    const Eigen::Vector3d a = at(surface(r, 0)), b = at(surface(r, 1)), c = at(surface(r, 2));
    if (NearestOnPlan((a + b + c) / 3.0).distance > tol) {
      opened_area_outside += 0.5 * (b - a).cross(c - a).norm();
      continue;
    }
    for (const Eigen::Vector3d& x : {a, b, c}) {
      const Nearest q = NearestOnPlan(x);
      if (q.distance <= tol) depth_reached = std::max(depth_reached, (q.point - x).dot(plan_.normal));
    }
    CoverCells(a, b, c, covered);
  }
  s.set_opened_area_outside(opened_area_outside);
  s.set_depth_reached(depth_reached);
  s.set_depth_error(depth_reached - plan_.depth);

  int64_t hit = 0;
  for (size_t k = 0; k < covered.size(); ++k) hit += covered[k] & in_tissue_[k];
  s.set_coverage(cells_in_tissue_ > 0 ? static_cast<double>(hit) / static_cast<double>(cells_in_tissue_) : 0.0);
  return s;
}

template IncisionScore IncisionScorer::Score<float>(const float*, const mesh::Triangles&, std::span<const uint8_t>,
                                                    const SessionMetrics&, double) const;
template IncisionScore IncisionScorer::Score<double>(const double*, const mesh::Triangles&, std::span<const uint8_t>,
                                                     const SessionMetrics&, double) const;

}  // namespace cutsim::sim
