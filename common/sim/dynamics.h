#pragma once
/// @file
/// The frame's dynamics: the tissue steps one physics frame under the
/// tool's contact, explicitly (symplectic Euler in stable substeps, the
/// contact force held on f_ext over each, the contact spring lowering the
/// substep) or implicitly (one backward Euler step of the whole frame,
/// fem::ImplicitIntegrator, with the contact spring inside the Newton
/// system as a fem::PenaltyTerm with its stiffness). The implicit step is
/// double precision only (integrator_choice.h refuses float).
///
/// With the implicit step the haptic linearisation is the step's own: the
/// tissue's point stiffness is EffectiveStiffness at the contact's nodes
/// minus the contact spring the last step put in its Jacobian, in series
/// with the contact spring (ToolStage::ContactStiffness).

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "common/fem/implicit.h"
#include "common/fem/integrator.h"
#include "common/sim/frame_times.h"
#include "common/sim/integrator_choice.h"
#include "common/sim/output.h"
#include "common/sim/scene_fem.h"
#include "common/sim/stage.h"
#include "common/sim/tool_stage.h"
#include "common/sim/types.h"

namespace cutsim::sim {

/// The implicit step's options for a scene: its time_step.implicit
/// stopping rules and mass damping, `threads` OpenMP threads; two or more,
/// or a run with a frame budget (`timed`: its steps depend on timing
/// anyway), factor on a worker thread beside the steps; one thread without
/// a budget factors inline (bit-reproducible runs and replays).
[[nodiscard]] fem::ImplicitOptions ImplicitOptionsFor(const v1::Scene& scene, int threads, bool timed = false);

template <typename T>
class Dynamics final : public CheckpointedStage {
 public:
  /// `options` serve the implicit step (unused by the explicit one).
  Dynamics(IntegratorKind kind, const fem::ImplicitOptions& options);
  ~Dynamics();
  Dynamics(const Dynamics&) = delete;
  Dynamics& operator=(const Dynamics&) = delete;

  [[nodiscard]] IntegratorKind kind() const { return kind_; }

  /// Steps `frame_time` seconds; the tool (or null) moved from `start` to
  /// its current pose over the frame. Sets run.last_dt. The implicit step
  /// stops at `deadline_ns` (CLOCK_MONOTONIC, 0: none) and carries its
  /// residual into the next frame; a Newton step that stops at its
  /// iteration cap or the deadline is counted and logged (the state keeps
  /// its last iterate). A step that fails (a non-finite residual or
  /// energy, e.g. a trial that inverts a patch) is redone from the same
  /// state in 2, then 4, then 8 substeps with the clamped tangent K⁺; only
  /// when all of them fail does the frame fail like an explicit step.
  fem::StepResult StepFrame(SceneFem<T>& fem, ToolStage<T>* tool, const ToolPose& start, double frame_time,
                            int64_t deadline_ns, RunCounters& run);

  /// The implicit step's first factor, made now at the state (load time;
  /// ImplicitIntegrator::Prime) for frames of `frame_time` s. No-op when
  /// explicit.
  void Prime(SceneFem<T>& fem, double frame_time);

  /// The haptic stiffness at the tool's contact (file comment), N/m.
  [[nodiscard]] Eigen::Matrix3d ContactStiffness(const ToolStage<T>& tool, const SceneFem<T>& fem) const;

  /// The integrator and the implicit step's counters.
  void AddToSummary(SimulationSummary& s) const;

  // ---- checkpoint part (stage.h): none -------------------------------------
  /// The explicit step keeps nothing between frames beyond the FEM state
  /// (SceneFem's part holds its step estimator). The implicit step's factor
  /// and the haptic stiffness it holds are caches, rebuilt on the first
  /// frame after a restore: an implicit scene resumes to within its Newton
  /// tolerances rather than bit for bit. Its counters start again.
  void Save(v1::CheckpointBody& /*body*/) const override {}
  void Check(const v1::CheckpointBody& /*body*/, const PartCheck& /*check*/) const override {}
  void Restore(const v1::CheckpointBody& /*body*/) override {}

  /// Wall time of the last frame's implicit phases, s (zero when explicit).
  [[nodiscard]] const std::array<double, kNumDynamicsPhases>& last_phase_seconds() const { return phase_seconds_; }

 private:
  fem::StepResult StepExplicit(SceneFem<T>& fem, ToolStage<T>* tool, const ToolPose& start, double frame_time,
                               RunCounters& run);
  fem::StepResult StepImplicit(SceneFem<T>& fem, ToolStage<T>* tool, const ToolPose& start, double frame_time,
                               int64_t deadline_ns, RunCounters& run);
  /// The recovery of a failed implicit step: `substeps` steps of
  /// frame_time/substeps with K⁺, the contact spring moved along the
  /// tool's path, each to its tolerance (no deadline: a recovery must not
  /// carry an error). False if one of them fails (the state is then
  /// restored).
  bool StepInSubsteps(SceneFem<T>& fem, ToolStage<T>* tool, const ToolPose& start, double frame_time,
                      int substeps);
  void Count(const fem::ImplicitResult& r, int64_t step);

  IntegratorKind kind_;
  // With kImplicit; mutable: EffectiveStiffness solves in its workspace.
  mutable std::unique_ptr<fem::ImplicitIntegrator> implicit_;
  std::vector<fem::PenaltyTerm> penalties_;  // the frame's contact spring, 0 or 1
  // The last whole-body tissue stiffness at the contact (held while the
  // estimate is refused), N/m.
  mutable Eigen::Matrix3d held_tissue_ = Eigen::Matrix3d::Zero();
  std::vector<double> saved_x_, saved_v_;    // the state before a recovery  // #N×3
  ImplicitCounters counters_;
  std::array<double, kNumDynamicsPhases> phase_seconds_{};  // the last frame's, s
};

extern template class Dynamics<float>;
extern template class Dynamics<double>;

}  // namespace cutsim::sim
