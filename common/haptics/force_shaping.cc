#include "common/haptics/force_shaping.h"

#include <algorithm>
#include <cmath>

namespace cutsim::haptics {

Eigen::Vector3d ApplyUnilateral(const Eigen::Vector3d& force, const Eigen::Vector3d& normal,
                                double tangential_ratio) noexcept {
  const double f_n = force.dot(normal);
  if (f_n <= 0.0) return Eigen::Vector3d::Zero();  // would pull: separated
  Eigen::Vector3d f_t = force - f_n * normal;
  const double t_max = tangential_ratio * f_n;
  const double t_norm = f_t.norm();
  if (t_norm > t_max) f_t *= t_max / t_norm;  // t_norm > t_max ≥ 0, so t_norm > 0
  return f_n * normal + f_t;
}

Eigen::Vector3d ClampMagnitude(const Eigen::Vector3d& force, double max_norm) noexcept {
  const double norm = force.norm();
  if (norm <= max_norm) return force;
  return force * (max_norm / norm);
}

Eigen::Vector3d LimitStep(const Eigen::Vector3d& previous, const Eigen::Vector3d& target,
                          double max_step) noexcept {
  const Eigen::Vector3d step = target - previous;
  const double norm = step.norm();
  if (norm <= max_step) return target;
  return previous + step * (max_step / norm);
}

BoundedModel BoundModel(const LocalModel& model, const DeviceLimits& limits) noexcept {
  BoundedModel b;
  b.contact = model.contact;
  if (!model.contact) return b;
  b.x0 = model.x0;
  b.normal = model.normal.normalized();  // Validate allowed a tiny deviation; remove it
  b.f0 = model.f0;
  // Validate accepted K as symmetric and PSD within tolerance; make it exact.
  b.stiffness = SymmetricPsdPart(model.stiffness);
  const double lambda_max = LargestEigenvalue(b.stiffness);
  if (lambda_max > limits.max_stiffness) {
    b.stiffness_scale = limits.max_stiffness / lambda_max;
    b.stiffness *= b.stiffness_scale;
  }
  b.damping = std::clamp(model.damping, 0.0, limits.max_damping);
  return b;
}

Eigen::Vector3d EvaluateBufferModel(const BoundedModel& model, const Eigen::Vector3d& x,
                                    const Eigen::Vector3d& v, double max_force,
                                    double tangential_ratio) noexcept {
  if (!model.contact) return Eigen::Vector3d::Zero();
  // Method paper §3.4 buffer model, first order about the contact: F = f0 + (∂f/∂x)(x − x0)
  // = f0 − K(x − x0) since the wire sends K = −∂f/∂x; plus viscous damping.
  const Eigen::Vector3d f = model.f0 - model.stiffness * (x - model.x0) - model.damping * v;
  return ClampMagnitude(ApplyUnilateral(f, model.normal, tangential_ratio), max_force);
}

}  // namespace cutsim::haptics
