#include "common/sim/incision_score.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace cutsim::sim {

IncisionScorer::IncisionScorer(PlannedIncision plan) : plan_(std::move(plan)) {
  for (size_t i = 1; i < plan_.points.size(); ++i) length_ += (plan_.points[i] - plan_.points[i - 1]).norm();
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
  s.cut_points = count_;
  s.mean_deviation = count_ > 0 ? sum_deviation_ / static_cast<double>(count_) : 0.0;
  s.max_deviation = max_deviation_;
  s.cut_off_volume = metrics.cut_off_volume;
  s.max_stress_outside = metrics.max_stress_outside;
  s.peak_force = metrics.peak_force;
  s.mean_force = metrics.mean_force;
  s.contact_time = metrics.contact_time;
  s.duration = sim_time;

  const auto at = [rest](int32_t v) {
    return Eigen::Vector3d(static_cast<double>(rest[3 * v]), static_cast<double>(rest[3 * v + 1]),
                           static_cast<double>(rest[3 * v + 2]));
  };
  const double tol = plan_.tolerance;
  const auto slots = std::min(static_cast<size_t>(surface.rows()), opened.size());
  for (size_t f = 0; f < slots; ++f) {
    const auto r = static_cast<Eigen::Index>(f);
    if (!opened[f] || surface(r, 0) < 0) continue;
    const Eigen::Vector3d a = at(surface(r, 0)), b = at(surface(r, 1)), c = at(surface(r, 2));
    if (NearestOnPlan((a + b + c) / 3.0).distance > tol) {
      s.opened_area_outside += 0.5 * (b - a).cross(c - a).norm();
      continue;
    }
    for (const Eigen::Vector3d& x : {a, b, c}) {
      const Nearest q = NearestOnPlan(x);
      if (q.distance <= tol) s.depth_reached = std::max(s.depth_reached, (q.point - x).dot(plan_.normal));
    }
  }
  s.depth_error = s.depth_reached - plan_.depth;

  // Coverage: the plan's length in bins of a tenth of the band; a cut point
  // in the band covers the bins within the band's half-width along the plan.
  if (length_ > 0.0) {
    const double bin = std::max(tol / 10.0, length_ / 10000.0);
    const auto bins = static_cast<size_t>(std::ceil(length_ / bin));
    std::vector<uint8_t> covered(bins, 0);
    for (const CutPoint& c : kept_) {
      const Nearest q = NearestOnPlan(c.rest);
      if (q.distance > tol) continue;
      const auto lo = static_cast<size_t>(std::max(0.0, std::floor((q.arc - tol) / bin)));
      const auto hi = std::min(bins, static_cast<size_t>(std::max(0.0, std::ceil((q.arc + tol) / bin))));
      for (size_t k = lo; k < hi; ++k) covered[k] = 1;
    }
    s.coverage = static_cast<double>(std::count(covered.begin(), covered.end(), uint8_t{1})) /
                 static_cast<double>(bins);
  }
  return s;
}

template IncisionScore IncisionScorer::Score<float>(const float*, const mesh::Triangles&, std::span<const uint8_t>,
                                                    const SessionMetrics&, double) const;
template IncisionScore IncisionScorer::Score<double>(const double*, const mesh::Triangles&, std::span<const uint8_t>,
                                                     const SessionMetrics&, double) const;

}  // namespace cutsim::sim
