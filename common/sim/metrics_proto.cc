#include "common/sim/metrics_proto.h"

#include <cmath>

#include <fmt/format.h>

#include "common/core/error.h"

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

}  // namespace cutsim::sim
