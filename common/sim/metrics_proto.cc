#include "common/sim/metrics_proto.h"

#include <cmath>

#include <fmt/format.h>

#include "common/core/error.h"
#include "common/sim/session_metrics.h"

namespace cutsim::sim {

void SessionMetricsToProto(const SessionMetrics& m, v1::SessionMetrics* out) {
  out->set_peak_force(m.peak_force);
  out->set_mean_force(m.mean_force);
  out->set_force_impulse(m.force_impulse);
  out->set_path_length(m.path_length);
  out->set_contact_time(m.contact_time);
  out->set_cut_off_volume(m.cut_off_volume);
  out->set_opened_area(m.opened_area);
  out->set_max_stress_outside(m.max_stress_outside);
  out->set_stress_outside(m.stress_outside);
  out->set_stress_samples(static_cast<double>(m.stress_samples));
}

SessionMetrics SessionMetricsFromProto(const v1::SessionMetrics& p, const std::string& source) {
  const struct {
    const char* name;
    double value;
  } fields[] = {{"peak_force", p.peak_force()},
                {"mean_force", p.mean_force()},
                {"force_impulse", p.force_impulse()},
                {"path_length", p.path_length()},
                {"contact_time", p.contact_time()},
                {"cut_off_volume", p.cut_off_volume()},
                {"opened_area", p.opened_area()},
                {"max_stress_outside", p.max_stress_outside()},
                {"stress_outside", p.stress_outside()},
                {"stress_samples", p.stress_samples()}};
  for (const auto& f : fields) {
    if (!std::isfinite(f.value) || f.value < 0.0) {
      ThrowInputError({.file = source, .field = fmt::format("metrics.{}", f.name)},
                      fmt::format("must be finite and not negative, got {}", f.value));
    }
  }
  if (p.mean_force() > p.peak_force() * (1.0 + 1e-9)) {
    ThrowInputError({.file = source, .field = "metrics.mean_force"},
                    fmt::format("{} N exceeds the peak force {} N", p.mean_force(), p.peak_force()));
  }
  if (p.stress_samples() > 9.0e15 || p.stress_samples() != std::floor(p.stress_samples())) {
    ThrowInputError({.file = source, .field = "metrics.stress_samples"},
                    fmt::format("must be a whole count below 9e15, got {}", p.stress_samples()));
  }
  return {.peak_force = p.peak_force(),
          .mean_force = p.mean_force(),
          .force_impulse = p.force_impulse(),
          .path_length = p.path_length(),
          .contact_time = p.contact_time(),
          .cut_off_volume = p.cut_off_volume(),
          .opened_area = p.opened_area(),
          .max_stress_outside = p.max_stress_outside(),
          .stress_outside = p.stress_outside(),
          .stress_samples = static_cast<int64_t>(p.stress_samples())};
}

void IncisionScoreToProto(const IncisionScore& s, v1::IncisionScore* out) {
  out->set_cut_points(static_cast<double>(s.cut_points));
  out->set_mean_deviation(s.mean_deviation);
  out->set_max_deviation(s.max_deviation);
  out->set_depth_reached(s.depth_reached);
  out->set_depth_error(s.depth_error);
  out->set_coverage(s.coverage);
  out->set_opened_area_outside(s.opened_area_outside);
  out->set_cut_off_volume(s.cut_off_volume);
  out->set_max_stress_outside(s.max_stress_outside);
  out->set_peak_force(s.peak_force);
  out->set_mean_force(s.mean_force);
  out->set_contact_time(s.contact_time);
  out->set_duration(s.duration);
}

PlannedIncision PlanOf(const v1::PlannedIncision& p) {
  PlannedIncision plan;
  for (const v1::Vec3& v : p.points()) plan.points.emplace_back(v.x(), v.y(), v.z());
  plan.normal = Eigen::Vector3d(p.normal().x(), p.normal().y(), p.normal().z()).normalized();
  plan.depth = p.depth();
  plan.tolerance = p.tolerance();
  return plan;
}

void SeriesToProto(std::span<const ForceSample> force, std::span<const CutPoint> cut_points, v1::CheckpointBody* out) {
  out->mutable_force_series()->Reserve(static_cast<int>(2 * force.size()));
  for (const ForceSample& f : force) {
    out->add_force_series(f.t);
    out->add_force_series(f.force);
  }
  out->mutable_cut_points()->Reserve(static_cast<int>(5 * cut_points.size()));
  for (const CutPoint& c : cut_points) {
    for (const double v : {c.t, c.rest.x(), c.rest.y(), c.rest.z(), c.deviation}) out->add_cut_points(v);
  }
}

SessionSeries SeriesFromProto(const v1::CheckpointBody& body, const std::string& source) {
  const auto check = [&source](const google::protobuf::RepeatedField<double>& values, const char* field, int row,
                               size_t max_rows) {
    const auto n = static_cast<size_t>(values.size());
    if (n % static_cast<size_t>(row) != 0 || n / static_cast<size_t>(row) > max_rows) {
      ThrowInputError({.file = source, .field = field},
                      fmt::format("{} values: must be whole rows of {} and at most {} rows", n, row, max_rows));
    }
    for (int i = 0; i < values.size(); ++i) {
      if (!std::isfinite(values[i])) {
        ThrowInputError({.file = source, .field = fmt::format("{}[{}]", field, i)}, "must be finite");
      }
    }
  };
  check(body.force_series(), "force_series", 2, SessionMeter<double>::kMaxForceSamples);
  check(body.cut_points(), "cut_points", 5, IncisionScorer::kMaxKeptCutPoints);
  SessionSeries s;
  const auto& f = body.force_series();
  for (int i = 0; i + 1 < f.size(); i += 2) s.force.push_back({.t = f[i], .force = f[i + 1]});
  const auto& c = body.cut_points();
  for (int i = 0; i + 4 < c.size(); i += 5) {
    s.cut_points.push_back({.t = c[i], .rest = Eigen::Vector3d(c[i + 1], c[i + 2], c[i + 3]), .deviation = c[i + 4]});
  }
  return s;
}

}  // namespace cutsim::sim
