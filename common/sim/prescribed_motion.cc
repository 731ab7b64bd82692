#include "common/sim/prescribed_motion.h"

#include <algorithm>

namespace cutsim::sim {

double RampFactor(double t, double ramp_time) {
  if (t < 0.0) return 0.0;
  if (!(ramp_time > 0.0) || t >= ramp_time) return 1.0;
  const double tau = t / ramp_time;
  return tau * tau * (3.0 - 2.0 * tau);
}

double RampRate(double t, double ramp_time) {
  if (t < 0.0 || !(ramp_time > 0.0) || t >= ramp_time) return 0.0;
  const double tau = t / ramp_time;
  return 6.0 * tau * (1.0 - tau) / ramp_time;
}

template <typename T>
void PrescribedMotion<T>::Add(fem::Model<T>& model, int32_t node, const Eigen::Vector3d& displacement,
                              double ramp_time) {
  model.SetFixed(node, true);
  entries_.push_back({.node = node, .displacement = displacement, .ramp_time = ramp_time});
}

template <typename T>
void PrescribedMotion<T>::Follow(std::span<const cutting::TopologyEvent> events) {
  if (entries_.empty()) {
    events_seen_ = events.size();
    return;
  }
  for (; events_seen_ < events.size(); ++events_seen_) {
    for (const cutting::Split& split : events[events_seen_].splits) {
      const size_t count = entries_.size();
      for (size_t i = 0; i < count; ++i) {
        if (entries_[i].node != split.node) continue;
        Entry copy = entries_[i];
        copy.node = split.new_node;
        entries_.push_back(copy);
      }
    }
  }
}

template <typename T>
void PrescribedMotion<T>::Apply(const fem::Model<T>& model, fem::State<T>& state, double t) const {
  const T* rest = model.rest_positions();
  for (const Entry& e : entries_) {
    const auto i = static_cast<size_t>(3 * e.node);
    for (int k = 0; k < 3; ++k) {
      state.x[i + static_cast<size_t>(k)] = rest[i + static_cast<size_t>(k)];
      state.v[i + static_cast<size_t>(k)] = T(0);
    }
  }
  for (const Entry& e : entries_) {
    const auto i = static_cast<size_t>(3 * e.node);
    const double s = RampFactor(t, e.ramp_time);
    const double rate = RampRate(t, e.ramp_time);
    for (int k = 0; k < 3; ++k) {
      state.x[i + static_cast<size_t>(k)] += static_cast<T>(s * e.displacement[k]);
      state.v[i + static_cast<size_t>(k)] += static_cast<T>(rate * e.displacement[k]);
    }
  }
}

template class PrescribedMotion<float>;
template class PrescribedMotion<double>;

}  // namespace cutsim::sim
