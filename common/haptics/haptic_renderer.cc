#include "common/haptics/haptic_renderer.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>

#include "common/core/error.h"

namespace cutsim::haptics {
namespace {

void Require(bool ok, std::string_view source, std::string_view field, std::string_view message) {
  if (!ok) {
    ThrowInputError(SourceRef{.field = std::string(source) + "." + std::string(field)}, message);
  }
}

bool Positive(double value) { return std::isfinite(value) && value > 0.0; }
bool NonNegative(double value) { return std::isfinite(value) && value >= 0.0; }

}  // namespace

void ValidateConfig(const RendererConfig& c, std::string_view source) {
  Require(Positive(c.device.max_force), source, "max_force", "must be a positive force in N");
  Require(Positive(c.device.max_stiffness), source, "max_stiffness", "must be a positive stiffness in N/m");
  Require(NonNegative(c.device.max_damping), source, "max_damping", "must be ≥ 0 N·s/m");
  Require(Positive(c.device.max_force_rate), source, "max_force_rate", "must be a positive rate in N/s");
  Require(Positive(c.watchdog), source, "watchdog", "must be a positive time in s");
  Require(Positive(c.fade), source, "fade", "must be a positive time in s");
  Require(c.watchdog + c.fade <= kMaxSilenceToZero + 1e-12, source, "watchdog",
          "watchdog + fade must be ≤ 0.1 s so force reaches zero within 100 ms of the last model");
  // The fade's steepest slope is (π/2)·max_force/fade; a slower rate limit
  // would stretch the fade past 100 ms.
  Require(c.device.max_force_rate * c.fade >= 0.5 * std::numbers::pi * c.device.max_force, source,
          "max_force_rate", "too low to fade max_force to zero within the fade time");
  Require(NonNegative(c.default_decay_per_second), source, "decay_per_second", "must be ≥ 0 1/s");
  Require(Positive(c.decay_blend), source, "decay_blend", "must be a positive time in s");
  Require(Positive(c.decay_floor) && c.decay_floor < 1.0, source, "decay_floor", "must be in (0, 1)");
  Require(NonNegative(c.tangential_ratio), source, "tangential_ratio", "must be ≥ 0");
  Require(Positive(c.max_dt), source, "max_dt", "must be a positive time in s");
  Require(NonNegative(c.passivity.max_damping), source, "passivity.max_damping", "must be ≥ 0 N·s/m");
  Require(Positive(c.passivity.min_speed), source, "passivity.min_speed", "must be a positive speed");
  Require(NonNegative(c.passivity.max_reserve), source, "passivity.max_reserve", "must be ≥ 0 J");
}

RendererConfig MakeRendererConfig(const HapticParamsView& p, std::string_view source) {
  RendererConfig c;
  Require(NonNegative(p.decay_per_second), source, "decay_per_second", "must be ≥ 0 1/s");
  Require(NonNegative(p.watchdog) && p.watchdog < kMaxSilenceToZero - 0.005, source, "watchdog",
          "must be in [0, 0.095) s (0 = 0.05) so force reaches zero within 100 ms");
  Require(NonNegative(p.max_force), source, "max_force", "must be ≥ 0 N (0 = default)");
  Require(NonNegative(p.max_stiffness), source, "max_stiffness", "must be ≥ 0 N/m (0 = default)");
  if (p.decay_per_second > 0.0) c.default_decay_per_second = p.decay_per_second;
  if (p.watchdog > 0.0) c.watchdog = p.watchdog;
  c.fade = std::min(c.fade, kMaxSilenceToZero - c.watchdog);
  if (p.max_force > 0.0) c.device.max_force = p.max_force;
  if (p.max_stiffness > 0.0) c.device.max_stiffness = p.max_stiffness;
  // Keep the rate limit fast enough for the fade (see ValidateConfig).
  c.device.max_force_rate =
      std::max(c.device.max_force_rate, 0.5 * std::numbers::pi * c.device.max_force / c.fade);
  ValidateConfig(c, source);
  return c;
}

HapticRenderer::HapticRenderer(const RendererConfig& config)
    : config_(config), passivity_(config.passivity) {
  ValidateConfig(config_);
  // The PC's braking reserve must know the output rate limit (passivity.h).
  PassivityConfig pc = config_.passivity;
  pc.force_rate = config_.device.max_force_rate;
  passivity_ = PassivityController(pc);
}

ModelUpdate HapticRenderer::SetModel(const LocalModel& model, int64_t receive_ns) noexcept {
  const ModelIssue issue = Validate(model, config_.validation);
  if (issue != ModelIssue::kOk) {
    ++stats_.models_rejected;
    ++stats_.rejected_by_issue[static_cast<size_t>(issue)];
    return ModelUpdate::kRejected;
  }
  if (have_model_ && model.seq <= last_seq_) {
    ++stats_.models_stale;  // out of order or duplicate: a stale force is worse than none
    return ModelUpdate::kStale;
  }
  ++stats_.models_accepted;
  have_model_ = true;
  last_seq_ = model.seq;
  last_receive_ns_ = receive_ns;
  model_ = BoundModel(model, config_.device);
  model_decay_ = model.cut.decay_per_second > 0.0 ? model.cut.decay_per_second
                                                  : config_.default_decay_per_second;

  if (!have_cut_baseline_ || model.cut.cuts < last_cuts_) {
    have_cut_baseline_ = true;  // first model, or the server's counter restarted
  } else if (model.cut.cuts > last_cuts_) {
    cut_pending_ = true;        // method paper §3.4: a cut was executed; switch on the next tick
    cut_seq_ = model.seq;
    newer_since_cut_ = false;
    decay_rate_ = model_decay_;
  } else if (model.seq > cut_seq_) {
    newer_since_cut_ = true;    // the cut's frame is over
  }
  last_cuts_ = model.cut.cuts;
  return ModelUpdate::kAccepted;
}

Eigen::Vector3d HapticRenderer::ModelStageForce(const Eigen::Vector3d& f_buffer, double dt) noexcept {
  if (cut_pending_) {
    cut_pending_ = false;
    ++stats_.cut_decays_started;
    // F_c: the force rendered at the moment of switching (method paper eq. 13), taken
    // before the watchdog gain so that gain and decay compose without a jump.
    decay_start_force_ = model_force_;
    decay_time_ = 0.0;
    phase_ = RenderPhase::kCutDecay;
  } else if (phase_ != RenderPhase::kBufferModel) {
    // Time since the switch: this tick's period. (Adding it after the
    // evaluation counted the period *before* the switch tick, so one late
    // wake just before a cut shifted the whole decay.)
    decay_time_ += dt;
  }
  if (phase_ == RenderPhase::kBufferModel) return f_buffer;

  // Method paper eq. (13) with I·Δt → t: F_c e^(−ξ t).
  const Eigen::Vector3d f_decay = CutDecayForce(decay_start_force_, decay_rate_, decay_time_);
  if (phase_ == RenderPhase::kCutDecay) {
    const double decayed = f_decay.norm();
    if (newer_since_cut_ && (decayed <= f_buffer.norm() ||
                             decayed <= config_.decay_floor * decay_start_force_.norm())) {
      phase_ = RenderPhase::kBlendBack;
      blend_phase_ = 0.0;
    } else {
      return f_decay;
    }
  }
  // Blend back: raised-cosine weight from the decaying cut force to the buffer model.
  const double b = RaisedCosine(blend_phase_);
  blend_phase_ += dt / config_.decay_blend;
  if (blend_phase_ >= 1.0 && b >= 1.0) phase_ = RenderPhase::kBufferModel;
  return (1.0 - b) * f_decay + b * f_buffer;
}

Eigen::Vector3d HapticRenderer::Tick(const Eigen::Vector3d& x, const Eigen::Vector3d& v, int64_t now_ns,
                                     double dt) noexcept {
  ++stats_.ticks;
  const bool dt_ok = std::isfinite(dt) && dt >= 0.0;
  const double h = dt_ok ? std::min(dt, config_.max_dt) : 0.0;  // s
  const bool inputs_ok = dt_ok && x.allFinite() && v.allFinite();
  if (!inputs_ok) ++stats_.non_finite_inputs;

  // Watchdog: fresh for `watchdog` s after the last accepted model arrived.
  const double age = have_model_ ? 1e-9 * static_cast<double>(now_ns - last_receive_ns_) : 1e300;
  const bool fresh = have_model_ && age <= config_.watchdog;
  if (fresh_ && !fresh) ++stats_.watchdog_trips;
  fresh_ = fresh;
  fade_phase_ = std::clamp(fade_phase_ + (fresh ? h : -h) / config_.fade, 0.0, 1.0);
  const double gain = RaisedCosine(fade_phase_);

  const Eigen::Vector3d f_buffer =
      inputs_ok ? EvaluateBufferModel(model_, x, v, config_.device.max_force, config_.tangential_ratio)
                : Eigen::Vector3d::Zero();
  model_force_ = ModelStageForce(f_buffer, h);

  Eigen::Vector3d f = gain * model_force_;
  if (inputs_ok && gain > 0.0) f = passivity_.Control(f, v, h);
  f = ClampMagnitude(f, config_.device.max_force);
  f = LimitStep(output_, f, config_.device.max_force_rate * h);
  if (!f.allFinite()) f = output_;  // cannot happen with finite inputs; output_ is finite by induction

  if (inputs_ok) passivity_.Observe(f, v, h);
  const double step = (f - output_).norm();
  output_ = f;

  stats_.max_force = std::max(stats_.max_force, f.norm());
  stats_.max_force_step = std::max(stats_.max_force_step, step);
  stats_.passivity_dissipated = passivity_.dissipated_energy();
  stats_.observed_energy = passivity_.observed_energy();
  stats_.min_observed_energy = passivity_.min_observed_energy();
  return f;
}

void HapticRenderer::Reset() noexcept {
  have_model_ = false;
  last_seq_ = 0;
  model_ = BoundedModel{};
  have_cut_baseline_ = false;
  last_cuts_ = 0;
  cut_pending_ = false;
  newer_since_cut_ = false;
  // phase_, decay state, fade phase and output stay: the force fades from
  // where it is (no model → stale → gain falls to 0 within `fade`).
}

}  // namespace cutsim::haptics
