#pragma once
/// @file
/// Pure per-tick force kernels of the haptic loop: the buffer model of the
/// method paper (§3.4) with its unilateral and device bounds, its cut-force
/// decay (eq. 13), and the safety limiters. Fixed-size Eigen only: no allocation,
/// no throw.

#include <cmath>

#include <Eigen/Core>

#include "common/haptics/local_model.h"

namespace cutsim::haptics {

/// What the device may be asked to do. Checked by `ValidateConfig` in
/// haptic_renderer.h.
struct DeviceLimits {
  double max_force = 8.0;          ///< N, magnitude bound of the commanded force.
  double max_stiffness = 2000.0;   ///< N/m, bound on K's largest eigenvalue.
  double max_damping = 20.0;       ///< N·s/m, bound on the model's damping.
  double max_force_rate = 2000.0;  ///< N/s, the output never steps more than this × dt per tick.
};

/// Unilateral contact rule ("the tissue only pushes"): with n the outward
/// normal and F_n = F·n,
///   * F_n < 0 (the linearised model would pull the tool back into the
///     tissue, e.g. once the tool has left the surface) is clamped to 0;
///   * the tangential part F_t = F − F_n n is bounded by `tangential_ratio`·F_n
///     (a friction-cone-like bound: without normal load there is no grip),
/// so the force goes to zero continuously as the tool leaves the surface.
[[nodiscard]] Eigen::Vector3d ApplyUnilateral(const Eigen::Vector3d& force, const Eigen::Vector3d& normal,
                                              double tangential_ratio) noexcept;

/// Scales `force` down to magnitude `max_norm` if larger (direction kept).
[[nodiscard]] Eigen::Vector3d ClampMagnitude(const Eigen::Vector3d& force, double max_norm) noexcept;

/// Moves from `previous` toward `target` by at most `max_step` (Euclidean).
[[nodiscard]] Eigen::Vector3d LimitStep(const Eigen::Vector3d& previous, const Eigen::Vector3d& target,
                                        double max_step) noexcept;

/// A model after the device bounds: K scaled so that λ_max(K) ≤
/// max_stiffness (scaling keeps K's shape, so the force direction field is
/// unchanged), damping clamped. Computed once per model, not per tick.
struct BoundedModel {
  bool contact = false;
  Eigen::Vector3d x0 = Eigen::Vector3d::Zero();      ///< m
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ(); ///< unit
  Eigen::Vector3d f0 = Eigen::Vector3d::Zero();      ///< N
  Eigen::Matrix3d stiffness = Eigen::Matrix3d::Zero();  ///< N/m, symmetric, λ_max ≤ max_stiffness
  double damping = 0.0;                              ///< N·s/m, ≤ max_damping
  double stiffness_scale = 1.0;                      ///< Factor applied to the model's K (≤ 1).
};

/// Applies `limits` to a model that passed `Validate`.
[[nodiscard]] BoundedModel BoundModel(const LocalModel& model, const DeviceLimits& limits) noexcept;

/// Buffer-model force on the tool at position x (m) and velocity v (m/s):
/// `F = f0 − K (x − x0) − damping · v`, then the unilateral rule, then
/// |F| ≤ max_force. No contact → zero.
///
/// Sign: the wire defines K = −∂f/∂x (symmetric PSD, like a spring
/// constant), so the first-order model is f0 + (∂f/∂x)(x − x0) =
/// f0 − K (x − x0): pushing into the tissue raises the outward force.
/// (Written "f0 + K(x − x0)" when K denotes ∂f/∂x, the same model.)
[[nodiscard]] Eigen::Vector3d EvaluateBufferModel(const BoundedModel& model, const Eigen::Vector3d& x,
                                                  const Eigen::Vector3d& v, double max_force,
                                                  double tangential_ratio) noexcept;

/// Cut-force decay, method paper eq. (13) with the iteration counter replaced by
/// time: `F_c · e^(−ξ t)` with ξ in 1/s and t = I·Δt the time since the
/// switch, so the decay does not depend on the loop rate (the method paper's
/// per-iteration ξ is ξ·Δt, i.e. ξ/1000 at 1 kHz).
[[nodiscard]] inline Eigen::Vector3d CutDecayForce(const Eigen::Vector3d& force_at_switch,
                                                   double decay_per_second, double time_since_switch) {
  return force_at_switch * std::exp(-decay_per_second * time_since_switch);
}

/// Raised-cosine ramp 0 → 1 on phase θ ∈ [0, 1]: zero slope at both ends,
/// so gains driven by it never produce a kink or step.
[[nodiscard]] inline double RaisedCosine(double phase) {
  const double p = phase < 0.0 ? 0.0 : (phase > 1.0 ? 1.0 : phase);
  return 0.5 * (1.0 - std::cos(3.14159265358979323846 * p));
}

}  // namespace cutsim::haptics
