#include "common/sim/session_metrics.h"

#include <algorithm>
#include <cmath>

#include "common/fem/element.h"
#include "common/fem/forces.h"

namespace cutsim::sim {

template <typename T>
SessionMeter<T>::SessionMeter(Options options) : options_(options) {
  metrics_.set_cutting_time(0.0);  // present from the start (an optional measure)
}

template <typename T>
void SessionMeter<T>::AddFrame(double frame_time, const ToolReport& tool) {
  if (!tool.present) return;
  if (have_tip_) metrics_.set_path_length(metrics_.path_length() + (tool.pose.tip - last_tip_).norm());
  last_tip_ = tool.pose.tip;
  have_tip_ = true;
  last_force_ = 0.0;
  if (tool.cut_this_frame) metrics_.set_cutting_time(metrics_.cutting_time() + frame_time);
  if (!tool.touching) return;
  const double f = tool.force_on_tool.norm();
  last_force_ = f;
  metrics_.set_peak_force(std::max(metrics_.peak_force(), f));
  metrics_.set_contact_time(metrics_.contact_time() + frame_time);
  metrics_.set_force_impulse(metrics_.force_impulse() + f * frame_time);
  metrics_.set_mean_force(metrics_.force_impulse() / metrics_.contact_time());
}

template <typename T>
bool SessionMeter<T>::SampleDue(double sim_time) const {
  // A small tolerance so a frame ending a hair before a period boundary
  // (accumulated rounding of the frame times) samples at that boundary.
  const auto slot = static_cast<int64_t>(std::floor(sim_time / options_.sample_period + 1e-6));
  return slot != last_sample_slot_;
}

template <typename T>
void SessionMeter<T>::Sample(const fem::Model<T>& model, const T* x, const IncisionView& incision, double sim_time) {
  last_sample_slot_ = static_cast<int64_t>(std::floor(sim_time / options_.sample_period + 1e-6));
  const auto nt = static_cast<size_t>(model.num_tets());
  if (cut_off_.size() != nt || model.topology_version() != pieces_version_) {
    UpdatePieces(model, incision);
    pieces_version_ = model.topology_version();
  }
  MarkIncision(model, x, incision);
  // Von Mises only (no principal stresses) and only where it counts.
  const auto count = static_cast<int64_t>(nt);
  const int threads = std::max(1, options_.threads);
  fem::ComputeNodePressures(model, x, tet_volume_, node_pressure_, threads);
  const std::span<const double> pressure(node_pressure_);
  double largest = 0.0;
#pragma omp parallel for schedule(static) num_threads(threads) reduction(max : largest)
  for (int64_t i = 0; i < count; ++i) {
    const auto t = static_cast<size_t>(i);
    if (cut_off_[t] || tet_mark_[t]) continue;
    const auto s =
        static_cast<double>(fem::VonMises<T>(fem::ElementCauchyStress(model, x, static_cast<int32_t>(i), pressure)));
    if (std::isfinite(s)) largest = std::max(largest, s);
  }
  metrics_.set_stress_outside(largest);
  metrics_.set_max_stress_outside(std::max(metrics_.max_stress_outside(), largest));
  metrics_.set_stress_samples(metrics_.stress_samples() + 1.0);
  if (series_.size() < kMaxForceSamples) series_.push_back({.t = sim_time, .force = last_force_});
}

template <typename T>
void SessionMeter<T>::UpdatePieces(const fem::Model<T>& model, const IncisionView& incision) {
  const int32_t nt = model.num_tets();
  cut_off_.assign(static_cast<size_t>(nt), 0);
  metrics_.set_cut_off_volume(0.0);
  metrics_.set_opened_area(0.0);
  if (incision.cut == nullptr) return;

  // Pieces: the anchored ones hold a fixed node; with none fixed anywhere,
  // the largest piece by rest volume is the body.
  int32_t count = 0;
  const std::vector<int32_t> label = incision.cut->ConnectedComponents(&count);
  std::vector<double> volume(static_cast<size_t>(count), 0.0);
  std::vector<uint8_t> anchored(static_cast<size_t>(count), 0);
  bool any_fixed = false;
  for (int32_t t = 0; t < nt; ++t) {
    const auto c = static_cast<size_t>(label[static_cast<size_t>(t)]);
    volume[c] += static_cast<double>(model.rest_volume(t));
    for (int k = 0; k < 4; ++k) {
      if (model.fixed(model.tet_node(t, k))) {
        anchored[c] = 1;
        any_fixed = true;
      }
    }
  }
  if (!any_fixed && count > 0) {
    anchored[static_cast<size_t>(std::max_element(volume.begin(), volume.end()) - volume.begin())] = 1;
  }
  double cut_off_volume = 0.0;
  for (int32_t t = 0; t < nt; ++t) {
    const auto c = static_cast<size_t>(label[static_cast<size_t>(t)]);
    if (anchored[c]) continue;
    cut_off_[static_cast<size_t>(t)] = 1;
    cut_off_volume += static_cast<double>(model.rest_volume(t));
  }
  metrics_.set_cut_off_volume(cut_off_volume);

  if (incision.surface == nullptr) return;
  const mesh::Triangles& tri = *incision.surface;
  const T* rest = model.rest_positions();
  auto at = [rest](int32_t n) {
    return Eigen::Vector3d(static_cast<double>(rest[3 * n]), static_cast<double>(rest[3 * n + 1]),
                           static_cast<double>(rest[3 * n + 2]));
  };
  const auto slots = std::min(static_cast<size_t>(tri.rows()), incision.opened.size());
  double opened_area = 0.0;
  for (size_t s = 0; s < slots; ++s) {
    const auto r = static_cast<Eigen::Index>(s);
    if (!incision.opened[s] || tri(r, 0) < 0) continue;
    opened_area += 0.5 * (at(tri(r, 1)) - at(tri(r, 0))).cross(at(tri(r, 2)) - at(tri(r, 0))).norm();
  }
  metrics_.set_opened_area(opened_area);
}

template <typename T>
void SessionMeter<T>::MarkIncision(const fem::Model<T>& model, const T* x, const IncisionView& incision) {
  const int32_t nt = model.num_tets();
  const int32_t nn = model.num_nodes();
  node_mark_.assign(static_cast<size_t>(nn), 0);
  tet_mark_.assign(static_cast<size_t>(nt), 0);
  const auto walls = std::min(incision.wall_nodes.size(), static_cast<size_t>(nn));
  for (size_t n = 0; n < walls; ++n) node_mark_[n] = incision.wall_nodes[n] != 0 ? 1 : 0;
  for (const int32_t n : incision.contact_nodes) {
    if (n >= 0 && n < nn) node_mark_[static_cast<size_t>(n)] = 1;
  }
  if (incision.blade_touching && incision.blade_radius > 0.0) {
    const Eigen::Vector3d a = incision.blade_tip;
    const Eigen::Vector3d d = incision.blade_dir;
    const double r2 = incision.blade_radius * incision.blade_radius;
    for (int32_t n = 0; n < nn; ++n) {
      const Eigen::Vector3d p(static_cast<double>(x[3 * n]), static_cast<double>(x[3 * n + 1]),
                              static_cast<double>(x[3 * n + 2]));
      const double s = std::clamp((p - a).dot(d), 0.0, incision.blade_length);
      if ((p - a - s * d).squaredNorm() <= r2) node_mark_[static_cast<size_t>(n)] = 1;
    }
  }
  // Ring 0: the tets on a node of the incision. Each further ring: the tets on a node
  // of the tets marked so far. Tets and nodes are marked in separate
  // passes, so each ring grows by exactly one layer.
  for (int ring = 0; ring <= options_.incision_rings; ++ring) {
    for (int32_t t = 0; t < nt; ++t) {
      if (tet_mark_[static_cast<size_t>(t)]) continue;
      for (int k = 0; k < 4; ++k) {
        if (node_mark_[static_cast<size_t>(model.tet_node(t, k))] == 1) {
          tet_mark_[static_cast<size_t>(t)] = 1;
          break;
        }
      }
    }
    if (ring == options_.incision_rings) break;
    for (int32_t t = 0; t < nt; ++t) {
      if (!tet_mark_[static_cast<size_t>(t)]) continue;
      for (int k = 0; k < 4; ++k) {
        node_mark_[static_cast<size_t>(model.tet_node(t, k))] = 1;
      }
    }
  }
}

template <typename T>
void SessionMeter<T>::Restore(const SessionMetrics& metrics, std::span<const ForceSample> series, double sim_time,
                              const Running& running) {
  metrics_ = metrics;
  series_.assign(series.begin(), series.begin() + static_cast<std::ptrdiff_t>(std::min(series.size(), kMaxForceSamples)));
  last_force_ = running.last_force;
  have_tip_ = running.have_tip;
  last_tip_ = running.last_tip;
  last_sample_slot_ = static_cast<int64_t>(std::floor(sim_time / options_.sample_period + 1e-6));
  pieces_version_ = ~uint64_t{0};
}

template class SessionMeter<float>;
template class SessionMeter<double>;

}  // namespace cutsim::sim
