#include "common/sim/metrics_proto.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <variant>

#include <fmt/format.h>

#include "common/core/error.h"
#include "common/sim/session_metrics.h"

namespace cutsim::sim {

SessionMetrics SessionMetricsFromProto(const v1::SessionMetrics& p, const std::string& source) {
  // Every measure, whatever the message holds, by its descriptor: a new
  // field is checked without a line here.
  const google::protobuf::Descriptor* descriptor = v1::SessionMetrics::descriptor();
  const google::protobuf::Reflection* reflection = v1::SessionMetrics::GetReflection();
  for (int i = 0; i < descriptor->field_count(); ++i) {
    const google::protobuf::FieldDescriptor* f = descriptor->field(i);
    if (f->cpp_type() != google::protobuf::FieldDescriptor::CPPTYPE_DOUBLE || f->is_repeated()) {
      ThrowInputError({.file = source, .field = fmt::format("metrics.{}", f->name())},
                      "the build's SessionMetrics message has a field that is not a double");
    }
    const double value = reflection->GetDouble(p, f);
    if (!std::isfinite(value) || value < 0.0) {
      ThrowInputError({.file = source, .field = fmt::format("metrics.{}", f->name())},
                      fmt::format("must be finite and not negative, got {}", value));
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
  return p;
}

namespace {

/// One value of the summary, by its type in the report.
using SummaryValue = std::variant<int64_t, double, bool, std::string>;

struct SummaryField {
  const char* name;
  SummaryValue (*get)(const SimulationSummary&);
};

// The summary's entries, once: every report that carries one of these names
// takes it from here.
#define CUTSIM_SUMMARY(name, expr) \
  {name, [](const SimulationSummary& s) -> SummaryValue { return expr; }}
constexpr SummaryField kSummaryFields[] = {
    CUTSIM_SUMMARY("scene", s.scene),
    CUTSIM_SUMMARY("precision", s.precision),
    CUTSIM_SUMMARY("nodes", int64_t{s.num_nodes}),
    CUTSIM_SUMMARY("tets", int64_t{s.num_tets}),
    CUTSIM_SUMMARY("free_nodes", int64_t{s.num_free_nodes}),
    CUTSIM_SUMMARY("threads", int64_t{s.threads}),
    CUTSIM_SUMMARY("steps", s.steps),
    CUTSIM_SUMMARY("frames", s.frames),
    CUTSIM_SUMMARY("dt", s.dt),
    CUTSIM_SUMMARY("stable_dt", s.stable_dt),
    CUTSIM_SUMMARY("sim_time", s.sim_time),
    CUTSIM_SUMMARY("wall_time", s.wall_time),
    CUTSIM_SUMMARY("tet_steps_per_s", s.tet_steps_per_s),
    CUTSIM_SUMMARY("realtime_factor", s.realtime_factor),
    CUTSIM_SUMMARY("kinetic_energy", s.kinetic_energy),
    CUTSIM_SUMMARY("strain_energy", s.strain_energy),
    CUTSIM_SUMMARY("residual_force", s.residual_force),
    CUTSIM_SUMMARY("max_displacement", s.max_displacement),
    CUTSIM_SUMMARY("at_rest", s.at_rest),
    CUTSIM_SUMMARY("status", s.status),
    CUTSIM_SUMMARY("diagnosis", s.diagnosis),
    CUTSIM_SUMMARY("cuts", static_cast<int64_t>(s.cuts)),
    CUTSIM_SUMMARY("cut_attempts", static_cast<int64_t>(s.cut_attempts)),
    CUTSIM_SUMMARY("cuts_rejected", static_cast<int64_t>(s.cuts_rejected)),
    CUTSIM_SUMMARY("topology_version", static_cast<int64_t>(s.topology_version)),
    CUTSIM_SUMMARY("components", int64_t{s.components}),
    CUTSIM_SUMMARY("opened_faces", int64_t{s.opened_faces}),
    CUTSIM_SUMMARY("min_rest_volume", s.min_rest_volume),
    CUTSIM_SUMMARY("total_mass", s.total_mass),
    CUTSIM_SUMMARY("cut_wall_time", s.cut_wall_time),
    CUTSIM_SUMMARY("integrator", s.integrator),
    CUTSIM_SUMMARY("newton_iterations", s.implicit.newton_iterations),
    CUTSIM_SUMMARY("max_newton_iterations", int64_t{s.implicit.max_newton_iterations}),
    CUTSIM_SUMMARY("pcg_iterations", s.implicit.pcg_iterations),
    CUTSIM_SUMMARY("max_pcg_iterations", int64_t{s.implicit.max_pcg_iterations}),
    CUTSIM_SUMMARY("unconverged_steps", s.implicit.unconverged_steps),
    CUTSIM_SUMMARY("factorizations", s.implicit.factorizations),
    CUTSIM_SUMMARY("tangent_assemblies", s.implicit.tangent_assemblies),
    CUTSIM_SUMMARY("out_of_time_steps", s.implicit.out_of_time_steps),
    CUTSIM_SUMMARY("max_residual_out_of_time", s.implicit.max_residual_out_of_time),
    CUTSIM_SUMMARY("max_residual_unconverged", s.implicit.max_residual_unconverged),
    CUTSIM_SUMMARY("recovered_steps", s.implicit.recovered_steps),
    CUTSIM_SUMMARY("factor_corrections", s.implicit.factor_corrections),
    CUTSIM_SUMMARY("over_budget_steps", s.implicit.over_budget_steps),
    CUTSIM_SUMMARY("max_correction_rank", int64_t{s.implicit.max_correction_rank}),
    CUTSIM_SUMMARY("max_correction_seconds", s.implicit.max_correction_seconds),
};
#undef CUTSIM_SUMMARY

/// `n` as a report count: uint32 (JSON prints it as a number, unlike 64-bit
/// integers), saturated to [0, 2^32 − 1].
uint32_t Count(int64_t n) {
  return static_cast<uint32_t>(std::clamp<int64_t>(n, 0, std::numeric_limits<uint32_t>::max()));
}

}  // namespace

void SummaryToReport(const SimulationSummary& summary, google::protobuf::Message* report) {
  using google::protobuf::FieldDescriptor;
  const google::protobuf::Descriptor* descriptor = report->GetDescriptor();
  const google::protobuf::Reflection* reflection = report->GetReflection();
  for (const SummaryField& entry : kSummaryFields) {
    const FieldDescriptor* f = descriptor->FindFieldByName(entry.name);
    if (f == nullptr) continue;
    const SummaryValue value = entry.get(summary);
    const auto mismatch = [&] {
      throw std::logic_error(fmt::format("{}.{}: the summary's value does not fit the field's type",
                                         descriptor->full_name(), f->name()));
    };
    if (f->is_repeated()) mismatch();
    if (const auto* n = std::get_if<int64_t>(&value)) {
      if (f->cpp_type() != FieldDescriptor::CPPTYPE_UINT32) mismatch();
      reflection->SetUInt32(report, f, Count(*n));
    } else if (const auto* d = std::get_if<double>(&value)) {
      if (f->cpp_type() != FieldDescriptor::CPPTYPE_DOUBLE) mismatch();
      reflection->SetDouble(report, f, *d);
    } else if (const auto* b = std::get_if<bool>(&value)) {
      if (f->cpp_type() != FieldDescriptor::CPPTYPE_BOOL) mismatch();
      reflection->SetBool(report, f, *b);
    } else {
      if (f->cpp_type() != FieldDescriptor::CPPTYPE_STRING) mismatch();
      reflection->SetString(report, f, std::get<std::string>(value));
    }
  }
}

std::vector<std::string> SummaryFieldNames() {
  std::vector<std::string> names;
  for (const SummaryField& entry : kSummaryFields) names.emplace_back(entry.name);
  return names;
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
