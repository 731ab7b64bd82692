#include "common/haptics/passivity.h"

#include <algorithm>
#include <cmath>

namespace cutsim::haptics {

Eigen::Vector3d PassivityController::Control(const Eigen::Vector3d& force, const Eigen::Vector3d& v,
                                             double dt) noexcept {
  last_damping_ = 0.0;
  if (!config_.enabled || !(dt > 0.0)) return force;
  const double speed = v.norm();  // s, m/s
  if (!(speed >= config_.min_speed)) return force;  // also catches NaN
  const double p = force.dot(v) / speed;  // N, component that delivers energy
  const double e = observed_energy_;      // J
  double p_max;                           // N, largest passive p this tick
  if (e >= 0.0) {
    const double r = config_.force_rate;
    p_max = r > 0.0 ? r * (std::sqrt(dt * dt + 2.0 * e / (speed * r)) - dt)  // with braking reserve
                    : e / (speed * dt);                                     // HR 2002
  } else {
    p_max = std::max(e / (speed * dt), -config_.max_damping * speed);  // recover the deficit
  }
  if (!(p > p_max)) return force;
  const double alpha = (p - p_max) / speed;  // N·s/m
  last_damping_ = alpha;
  dissipated_energy_ += alpha * speed * speed * dt;
  return force - alpha * v;
}

void PassivityController::Observe(const Eigen::Vector3d& commanded, const Eigen::Vector3d& v,
                                  double dt) noexcept {
  if (!(dt > 0.0) || !v.allFinite() || !commanded.allFinite()) return;
  observed_energy_ -= commanded.dot(v) * dt;
  min_observed_energy_ = std::min(min_observed_energy_, observed_energy_);
  observed_energy_ = std::min(observed_energy_, config_.max_reserve);
}

void PassivityController::Reset() noexcept {
  observed_energy_ = 0.0;
  min_observed_energy_ = 0.0;
  dissipated_energy_ = 0.0;
  last_damping_ = 0.0;
}

}  // namespace cutsim::haptics
