#include "common/sim/dynamics.h"

#include <algorithm>
#include <type_traits>

#include "common/core/log.h"
#include "common/core/stop.h"

namespace cutsim::sim {

fem::ImplicitOptions ImplicitOptionsFor(const v1::Scene& scene, int threads, bool timed) {
  const v1::ImplicitSolver& s = scene.time_step().implicit();
  fem::ImplicitOptions options;
  options.mass_damping = scene.mass_damping();
  options.asynchronous_factorization = threads >= 2 || timed;
  // The factor worker gets a core of its own: the step's team leaves it
  // one, so a factorisation never competes with the frame for a core.
  options.num_threads = options.asynchronous_factorization && threads >= 2 ? threads - 1 : threads;
  options.force_tolerance = s.force_tolerance();
  if (s.linear_tolerance() > 0) options.linear_tolerance = s.linear_tolerance();
  if (s.max_newton_iterations() > 0) options.max_newton_iterations = s.max_newton_iterations();
  return options;
}

template <typename T>
Dynamics<T>::Dynamics(IntegratorKind kind, const fem::ImplicitOptions& options) : kind_(kind) {
  if (kind_ != IntegratorKind::kImplicit) return;
  implicit_ = std::make_unique<fem::ImplicitIntegrator>(options);
  penalties_.reserve(1);
}

template <typename T>
Dynamics<T>::~Dynamics() = default;

template <typename T>
fem::StepResult Dynamics<T>::StepFrame(SceneFem<T>& fem, ToolStage<T>* tool, const ToolPose& start,
                                       double frame_time, int64_t deadline_ns, RunCounters& run) {
  phase_seconds_.fill(0.0);
  if (kind_ == IntegratorKind::kImplicit) return StepImplicit(fem, tool, start, frame_time, deadline_ns, run);
  return StepExplicit(fem, tool, start, frame_time, run);
}

/// Substeps under fem's substep rule, the contact-limited bound lowering
/// each while the tool loads the tissue, and the contact force refreshed
/// before each for the tip interpolated over the frame.
template <typename T>
fem::StepResult Dynamics<T>::StepExplicit(SceneFem<T>& fem, ToolStage<T>* tool, const ToolPose& start,
                                          double frame_time, RunCounters& run) {
  fem::Model<T>& model = fem.model();
  fem::State<T>& state = fem.state();
  const fem::StepOptions& options = fem.step_options();
  const Eigen::Vector3d end_tip = tool ? tool->pose().tip : start.tip;
  const Eigen::Vector3d tool_velocity = (end_tip - start.tip) / frame_time;
  fem::StepResult r;
  double remaining = frame_time;
  double elapsed = 0;
  while (remaining > 0) {
    const bool loaded = tool && tool->Loaded();
    double dt_max = static_cast<double>(fem::CurrentTimeStep(model, state, options));
    if (loaded) dt_max = tool->ContactLimitedStep(dt_max, model, options.safety_factor);
    const fem::Substep sub = fem::EqualSubstep(remaining, dt_max);
    if (loaded) {
      const double s = (elapsed + sub.dt) / frame_time;
      tool->ApplyContactForce(start.tip + s * (end_tip - start.tip), tool_velocity, state);
    }
    r = fem::Step(model, state, static_cast<T>(sub.dt), options);
    if (!r.ok()) break;
    run.last_dt = r.dt > 0 ? r.dt : sub.dt;
    remaining -= sub.dt;
    elapsed += sub.dt;
    if (sub.last) break;
    // A stop request ends the frame after this sub-step: the state is the
    // last completed sub-step's, so a shutdown never waits for a long frame.
    if (StopRequested()) break;
  }
  if (tool) tool->ClearContactForce(state);
  return r;
}

/// One backward Euler step of the frame with the contact spring for the
/// tip at the frame's end; the report then shows the force at the step's
/// end positions.
template <typename T>
fem::StepResult Dynamics<T>::StepImplicit(SceneFem<T>& fem, ToolStage<T>* tool, const ToolPose& start,
                                          double frame_time, int64_t deadline_ns, RunCounters& run) {
  fem::StepResult r;
  if constexpr (std::is_same_v<T, double>) {
    fem::Model<double>& model = fem.model();
    fem::State<double>& state = fem.state();
    penalties_.clear();
    const Eigen::Vector3d end_tip = tool ? tool->pose().tip : start.tip;
    const Eigen::Vector3d tool_velocity = (end_tip - start.tip) / frame_time;
    if (tool && tool->Loaded()) penalties_.push_back(tool->ContactPenalty(end_tip, tool_velocity, state.x.data()));
    const int64_t step_before = state.step;
    const fem::ImplicitResult result = implicit_->Step(model, state, frame_time, penalties_, deadline_ns);
    Count(result, state.step);
    r.step = state.step;
    r.dt = frame_time;
    r.substeps = 1;
    if (!result.advanced()) {
      bool recovered = false;
      for (const int substeps : {2, 4, 8}) {
        if ((recovered = StepInSubsteps(fem, tool, start, frame_time, substeps))) {
          r.substeps = substeps;
          break;
        }
      }
      if (!recovered) {
        r.status = fem::StepStatus::kNoAdmissibleIterate;
        r.step = step_before;
        r.quantity = "implicit residual";
        r.value = result.residual;
        return r;
      }
      ++counters_.recovered_steps;
      if (counters_.recovered_steps <= 3 || counters_.recovered_steps % 100 == 0) {
        Log().warn("implicit step {}: the frame's step failed (a non-finite trial); redone in {} substeps with K⁺ "
                   "({} such frames so far)",
                   step_before, r.substeps, counters_.recovered_steps);
      }
    }
    if (tool && tool->Loaded()) (void)tool->ContactPenalty(end_tip, tool_velocity, state.x.data());
    run.last_dt = frame_time / r.substeps;
  } else {
    (void)fem, (void)tool, (void)start, (void)frame_time, (void)deadline_ns, (void)run;
  }
  return r;
}

template <typename T>
bool Dynamics<T>::StepInSubsteps(SceneFem<T>& fem, ToolStage<T>* tool, const ToolPose& start, double frame_time,
                                 int substeps) {
  if constexpr (std::is_same_v<T, double>) {
    fem::Model<double>& model = fem.model();
    fem::State<double>& state = fem.state();
    saved_x_.assign(state.x.begin(), state.x.end());
    saved_v_.assign(state.v.begin(), state.v.end());
    const double time = state.time;
    const int64_t step = state.step;
    fem::ImplicitOptions& options = implicit_->mutable_options();
    const fem::TangentMode mode = options.tangent;
    options.tangent = fem::TangentMode::kClamped;
    const Eigen::Vector3d end_tip = tool ? tool->pose().tip : start.tip;
    const Eigen::Vector3d tool_velocity = (end_tip - start.tip) / frame_time;
    const double h = frame_time / substeps;
    bool ok = true;
    for (int i = 1; i <= substeps && ok; ++i) {
      penalties_.clear();
      const Eigen::Vector3d tip = start.tip + (static_cast<double>(i) / substeps) * (end_tip - start.tip);
      if (tool && tool->Loaded()) penalties_.push_back(tool->ContactPenalty(tip, tool_velocity, state.x.data()));
      const fem::ImplicitResult result = implicit_->Step(model, state, h, penalties_);
      Count(result, state.step);
      ok = result.advanced();
    }
    options.tangent = mode;
    if (ok) return true;
    std::copy(saved_x_.begin(), saved_x_.end(), state.x.begin());
    std::copy(saved_v_.begin(), saved_v_.end(), state.v.begin());
    state.time = time;
    state.step = step;
    return false;
  } else {
    (void)fem, (void)tool, (void)start, (void)frame_time, (void)substeps;
    return false;
  }
}

template <typename T>
void Dynamics<T>::Count(const fem::ImplicitResult& r, int64_t step) {
  for (size_t p = 0; p < phase_seconds_.size(); ++p) phase_seconds_[p] += r.phase_seconds[p];
  ImplicitCounters& c = counters_;
  ++c.steps;
  c.newton_iterations += r.newton_iterations;
  c.max_newton_iterations = std::max(c.max_newton_iterations, r.newton_iterations);
  c.pcg_iterations += r.pcg_iterations;
  c.max_pcg_iterations = std::max(c.max_pcg_iterations, r.pcg_iterations);
  // The factor and correction counts are the solver's own: both are made
  // on worker threads and land a few steps after they are asked for.
  const fem::FactorStats fs = implicit_->linear_solver().stats();
  c.factorizations = fs.completed;
  c.factor_corrections = fs.corrections;
  c.max_correction_rank = fs.max_correction_rank;
  c.max_correction_seconds = fs.max_correction_seconds;
  c.tangent_assemblies += r.tangent_assemblies;
  c.over_budget_steps += r.over_budget ? 1 : 0;
  if (r.status == fem::ImplicitStatus::kOutOfTime) {
    ++c.out_of_time_steps;
    c.max_residual_out_of_time = std::max(c.max_residual_out_of_time, r.residual);
    return;
  }
  if (r.status != fem::ImplicitStatus::kCapped) return;
  ++c.unconverged_steps;
  c.max_residual_unconverged = std::max(c.max_residual_unconverged, r.residual);
  // The first few and then every hundredth: visible without flooding the log.
  if (c.unconverged_steps <= 3 || c.unconverged_steps % 100 == 0) {
    Log().warn("implicit step {}: Newton stopped at {} iterations, residual {:.3g} N > tolerance {:.3g} N "
               "({} such steps so far)",
               step, r.newton_iterations, r.residual, r.tolerance, c.unconverged_steps);
  }
}

template <typename T>
void Dynamics<T>::Prime(SceneFem<T>& fem, double frame_time) {
  if constexpr (std::is_same_v<T, double>) {
    if (kind_ == IntegratorKind::kImplicit) implicit_->Prime(fem.model(), fem.state(), frame_time);
  } else {
    (void)fem, (void)frame_time;
  }
}

template <typename T>
Eigen::Matrix3d Dynamics<T>::ContactStiffness(const ToolStage<T>& tool, const SceneFem<T>& fem) const {
  if constexpr (std::is_same_v<T, double>) {
    // Without load the stiffness is zero (ToolStage): no tangent to assemble,
    // and the next contact starts without a held stiffness.
    if (!tool.Loaded()) held_tissue_.setZero();
    if (kind_ == IntegratorKind::kImplicit && tool.Loaded()) {
      // While the factor lags a cut the last stiffness holds: it was taken
      // a few frames ago on a nearby facet, and the estimate would cost
      // several times its usual preconditioner applications.
      if (!held_tissue_.isZero() && !implicit_->FactorIsCurrent()) return tool.ContactStiffness(held_tissue_);
      const std::array<int32_t, 3>& nodes = tool.force_nodes();
      const Eigen::Vector3d& w = tool.force_weights();
      const std::array<double, 3> weights{w[0], w[1], w[2]};
      Eigen::Matrix3d tissue = implicit_->EffectiveStiffness(fem.model(), nodes, weights);
      if (tissue.isZero()) {
        // No whole-body answer this frame (the estimate was refused, as
        // after a cut before the factor catches up): the last one holds, it
        // was taken a few frames ago on a nearby facet; before any, the
        // static patch around the contact.
        if (!held_tissue_.isZero()) return tool.ContactStiffness(held_tissue_);
        return tool.ContactStiffness(fem.model(), fem.state().x.data());
      }
      held_tissue_ = tissue;
      return tool.ContactStiffness(tissue);
    }
  }
  return tool.ContactStiffness(fem.model(), fem.state().x.data());
}

template <typename T>
void Dynamics<T>::AddToSummary(SimulationSummary& s) const {
  s.integrator = IntegratorName(kind_);
  s.implicit = counters_;
}

template class Dynamics<float>;
template class Dynamics<double>;

}  // namespace cutsim::sim
