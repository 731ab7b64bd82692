#pragma once
/// @file
/// The 1 kHz haptic rendering loop's math in one object: takes local models
/// as they arrive (`SetModel`) and turns the device state into the force to
/// command (`Tick`). Pipeline per tick:
///
///   buffer model (method paper §3.4; unilateral, λ_max(K) and |F| bounded)
///   └─ or cut-force decay F_c·e^(−ξt) (method paper eq. 13) after a cut, blended back
///   × watchdog gain (raised-cosine fade to 0 when the server goes silent)
///   → passivity controller (Hannaford–Ryu variable damper)
///   → |F| ≤ max_force → |ΔF| ≤ max_force_rate·Δt → finite check → device
///
/// Rules (tested in tests/unit/haptics):
/// * Models: a model is rendered only if `Validate` accepts it (else counted
///   as rejected, by reason) and its seq is greater than every accepted seq
///   (else counted as stale: out of order or duplicated). A restarted server
///   (seq back to 0) needs `Reset()`; until then the watchdog fades to 0.
/// * Watchdog: a model is fresh for `watchdog` seconds after its receive
///   time (our clock; the server's stamp is another host's clock). When
///   stale, a phase θ falls at 1/fade per second and the gain is
///   ½(1 − cos πθ): full force until `watchdog`, zero by `watchdog + fade`
///   (≤ 100 ms, enforced by `ValidateConfig`). A fresh model raises θ the
///   same way, so force blends back in over `fade` without a jump. The
///   server's `valid_for` is validated but does not shorten the watchdog: a
///   one-frame horizon plus network jitter would trip it on every late frame.
/// * Cut decay: a cut is an increase of the model's cut counter (the first
///   model only sets the baseline; a decrease re-baselines). On the next tick
///   the renderer switches to F_c·e^(−ξt), F_c = the model-stage force of the
///   previous tick (so the switch is continuous), ξ from the model (or the
///   default), t = Σ Δt since the switch. Another cut restarts the decay from
///   the current decayed force. The decay ends once a model newer than the
///   cut's has arrived (the cut frame is over) and either the decayed force
///   is no larger than the buffer-model force or it has fallen below
///   `decay_floor`·|F_c|; the force then blends from the (still decaying)
///   cut force to the buffer model over `decay_blend` seconds.
/// * Passivity: see passivity.h (Hannaford–Ryu PO/PC with a braking reserve
///   sized by max_force_rate, so the PC never needs a step beyond the rate
///   limit). The PC acts only while the watchdog gain is non-zero, so a
///   silent server always ends at exactly zero force.
/// * Bad device input (non-finite x or v) renders as no contact (the force
///   ramps to 0 at the rate limit) and is counted; a NaN never leaves `Tick`.
///
/// `SetModel` and `Tick` never allocate or throw. Not thread-safe: call both
/// from the haptic loop's thread (hand models over from the transport thread
/// through a mailbox).

#include <array>
#include <cstdint>
#include <string_view>

#include <Eigen/Core>

#include "common/haptics/force_shaping.h"
#include "common/haptics/local_model.h"
#include "common/haptics/passivity.h"

namespace cutsim::haptics {

/// Longest time from the last model to zero force, s (watchdog + fade).
inline constexpr double kMaxSilenceToZero = 0.1;

/// Renderer settings. Defaults are a PHANToM-class desktop device.
struct RendererConfig {
  DeviceLimits device;
  double watchdog = 0.05;                  ///< s without a fresh model before the fade starts.
  double fade = 0.05;                      ///< s, fade duration (watchdog + fade ≤ 0.1 s).
  double default_decay_per_second = 30.0;  ///< ξ, 1/s, when the model sends 0.
  double decay_blend = 0.02;               ///< s, blend from the cut decay back to the buffer model.
  double decay_floor = 0.01;               ///< Fraction of |F_c| at which the decay counts as done.
  double tangential_ratio = 1.0;           ///< Unilateral rule: |F_t| ≤ ratio · F_n.
  double max_dt = 0.01;                    ///< s, longer ticks (a stalled loop) are clamped.
  PassivityConfig passivity;
  ValidationLimits validation;
};

/// The scene's `HapticParams` fields (0 = default), free of protobuf.
struct HapticParamsView {
  double decay_per_second = 0.0;  ///< 1/s
  double watchdog = 0.0;          ///< s
  double max_force = 0.0;         ///< N
  double max_stiffness = 0.0;     ///< N/m
};

/// Renderer config from scene parameters; the fade shortens so that
/// watchdog + fade ≤ 0.1 s. Throws `InputError` naming the
/// `<source>.<field>` for out-of-range values (construction time only).
[[nodiscard]] RendererConfig MakeRendererConfig(const HapticParamsView& params,
                                                std::string_view source = "haptics");

/// Throws `InputError` (field `<source>.<name>`) if a setting is out of range.
void ValidateConfig(const RendererConfig& config, std::string_view source = "haptics");

/// Counters for logs and tests.
struct RendererStats {
  uint64_t ticks = 0;
  uint64_t models_accepted = 0;
  uint64_t models_rejected = 0;   ///< Failed `Validate`.
  uint64_t models_stale = 0;      ///< seq not newer than the last accepted one.
  std::array<uint64_t, kModelIssueCount> rejected_by_issue{};  ///< Indexed by ModelIssue.
  uint64_t watchdog_trips = 0;    ///< Fresh → stale transitions.
  uint64_t cut_decays_started = 0;
  uint64_t non_finite_inputs = 0; ///< Ticks with non-finite x, v (or dt).
  double passivity_dissipated = 0.0;  ///< J, Σ α|v|²Δt of the PC.
  double observed_energy = 0.0;       ///< J, current E_obs (≥ 0: passive so far).
  double min_observed_energy = 0.0;   ///< J, lowest E_obs seen.
  double max_force = 0.0;             ///< N, largest |F| commanded.
  double max_force_step = 0.0;        ///< N, largest |F(n) − F(n−1)|.
};

/// Result of `SetModel`.
enum class ModelUpdate : uint8_t { kAccepted, kRejected, kStale };

/// Which force source the renderer is in.
enum class RenderPhase : uint8_t { kBufferModel, kCutDecay, kBlendBack };

/// Haptic rendering state for one device.
class HapticRenderer {
 public:
  /// Validates `config` (throws `InputError`).
  explicit HapticRenderer(const RendererConfig& config = {});

  /// Offers a model received at `receive_ns` (our CLOCK_MONOTONIC).
  ModelUpdate SetModel(const LocalModel& model, int64_t receive_ns) noexcept;

  /// One loop iteration: tool position x (m), velocity v (m/s), now (ns, our
  /// clock), tick length dt (s). Returns the force to command, N; always finite.
  Eigen::Vector3d Tick(const Eigen::Vector3d& x, const Eigen::Vector3d& v, int64_t now_ns,
                       double dt) noexcept;

  /// Forgets the model stream (seq, cut baseline), e.g. after a server
  /// restart. The force fades out from where it is; nothing jumps.
  void Reset() noexcept;

  [[nodiscard]] const RendererStats& stats() const { return stats_; }
  [[nodiscard]] const RendererConfig& config() const { return config_; }
  [[nodiscard]] const PassivityController& passivity() const { return passivity_; }
  [[nodiscard]] RenderPhase phase() const { return phase_; }
  [[nodiscard]] double watchdog_gain() const { return RaisedCosine(fade_phase_); }
  [[nodiscard]] const Eigen::Vector3d& last_force() const { return output_; }

 private:
  Eigen::Vector3d ModelStageForce(const Eigen::Vector3d& f_buffer, double dt) noexcept;

  RendererConfig config_;
  PassivityController passivity_;
  RendererStats stats_;

  // Model stream.
  bool have_model_ = false;
  uint64_t last_seq_ = 0;
  int64_t last_receive_ns_ = 0;
  BoundedModel model_;
  double model_decay_ = 0.0;  // ξ of the current model (or default), 1/s

  // Watchdog.
  bool fresh_ = false;
  double fade_phase_ = 0.0;  // θ ∈ [0, 1]; gain = RaisedCosine(θ)

  // Cut decay.
  bool have_cut_baseline_ = false;
  uint64_t last_cuts_ = 0;
  bool cut_pending_ = false;
  uint64_t cut_seq_ = 0;           // seq of the model that reported the cut
  bool newer_since_cut_ = false;   // a model after the cut's has arrived
  RenderPhase phase_ = RenderPhase::kBufferModel;
  Eigen::Vector3d decay_start_force_ = Eigen::Vector3d::Zero();  // F_c, N
  double decay_rate_ = 0.0;        // ξ, 1/s
  double decay_time_ = 0.0;        // t since the switch, s
  double blend_phase_ = 0.0;       // 0 → 1 over decay_blend

  // Forces.
  Eigen::Vector3d model_force_ = Eigen::Vector3d::Zero();  // last model-stage force, N
  Eigen::Vector3d output_ = Eigen::Vector3d::Zero();       // last commanded force, N
};

}  // namespace cutsim::haptics
