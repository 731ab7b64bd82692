#pragma once
/// @file
/// Time-domain passivity observer (PO) and controller (PC) on the device
/// port, after Hannaford & Ryu, "Time-domain passivity control of haptic
/// interfaces", IEEE T-RA 18(1), 2002. The buffer model, delay and jitter in
/// the model stream, and zero-order hold can make the virtual environment
/// generate energy (a delayed stiff wall pushes back harder than it was
/// pushed); the PO measures that and the PC removes it with a variable damper.
///
/// Sign convention. F is the force commanded to the device (the force on the
/// user's tool), v the tool velocity. The power flowing from the user into the
/// virtual environment through the port is P = −F·v (the user pushes against
/// F), and the observer integrates it:
///
///   E_obs(n) = Σ_k −F(k)·v(k)·Δt(k)      (Hannaford–Ryu PO, eq. 7 form)
///
/// E_obs ≥ 0 always means the environment has only stored or dissipated
/// energy (passive); E_obs < 0 means it has delivered net energy to the user,
/// i.e. generated it. Equivalently E_obs integrates F_u·v with F_u = −F the
/// force the user applies to the environment.
///
/// Controller (HR 2002 eq. 11, impedance causality). Before a force F is
/// commanded, with s = |v|, v̂ = v/s and p = F·v̂ the force component that
/// delivers energy, the PC lowers p to p_max by a damper along the velocity,
///   F' = F − α v,   α = (p − p_max)/s ≥ 0,
/// choosing the least damping that keeps the port passive:
///   classic HR:  E_obs − p'·s·Δt ≥ 0                  → p_max = E_obs/(s Δt)
/// cutsim adds a braking reserve so the controller never needs a force step
/// larger than the rate limit R (N/s): the energy that will still flow while
/// a rate-limited force along v̂ ramps from p' to 0 is ≈ s·p'²/(2R), so
///   E_obs − p'·s·Δt ≥ s·p'²/(2R)   → p_max = R(√(Δt² + 2E_obs/(sR)) − Δt),
/// which tends to the classic rule as R → ∞ and, tick to tick, moves p_max
/// by at most R·Δt. |α v| ≤ |F|, so the damper never pushes harder than
/// the environment does. If E_obs is already negative (a deficit left by the
/// magnitude or rate limit), the PC recovers it with a damper capped at
/// `max_damping`. Below `min_speed` the PC does not act. O(1), no allocation.

#include <Eigen/Core>

namespace cutsim::haptics {

/// Passivity controller settings.
struct PassivityConfig {
  bool enabled = true;         ///< false = observe only (for tests and diagnosis).
  double force_rate = 0.0;     ///< N/s, output rate limit R for the braking reserve; 0 = classic HR.
  double max_damping = 200.0;  ///< N·s/m, cap on the damper that recovers an existing deficit.
  double min_speed = 1e-5;     ///< m/s, below this the PC does not act.
  /// J, cap on the stored-energy credit. The PO counts energy the user stored
  /// in elastic tissue as credit; a long session could bank enough to hide a
  /// later instability. Capping the credit keeps the PC responsive.
  double max_reserve = 1.0;
};

/// Observer + controller state for one device port.
class PassivityController {
 public:
  PassivityController() = default;
  explicit PassivityController(const PassivityConfig& config) : config_(config) {}

  /// Returns `force` (N) with the PC damper added for this tick, given the
  /// tool velocity v (m/s) and the tick length dt (s). Does not change E_obs.
  [[nodiscard]] Eigen::Vector3d Control(const Eigen::Vector3d& force, const Eigen::Vector3d& v,
                                        double dt) noexcept;

  /// Integrates the force actually commanded this tick (after any limiting)
  /// into the observer.
  void Observe(const Eigen::Vector3d& commanded, const Eigen::Vector3d& v, double dt) noexcept;

  /// Clears the observer (e.g. after the device was disabled).
  void Reset() noexcept;

  /// E_obs, J: net energy that has flowed from the user into the environment.
  [[nodiscard]] double observed_energy() const { return observed_energy_; }
  /// Smallest E_obs seen, J (negative = the environment was active at some time).
  [[nodiscard]] double min_observed_energy() const { return min_observed_energy_; }
  /// Energy the PC's damper was set to dissipate, J (Σ α|v|²Δt).
  [[nodiscard]] double dissipated_energy() const { return dissipated_energy_; }
  /// α of the last `Control` call, N·s/m.
  [[nodiscard]] double last_damping() const { return last_damping_; }
  [[nodiscard]] const PassivityConfig& config() const { return config_; }

 private:
  PassivityConfig config_;
  double observed_energy_ = 0.0;      // J
  double min_observed_energy_ = 0.0;  // J
  double dissipated_energy_ = 0.0;    // J
  double last_damping_ = 0.0;         // N·s/m
};

}  // namespace cutsim::haptics
