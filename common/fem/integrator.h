#pragma once
/// @file
/// Time integration: symplectic Euler (v += dt·M⁻¹f, then x += dt·v; the
/// method paper's "modified Euler"), fixed nodes not integrated, substepping to a
/// frame time under the stable-step bound (EqualSubstep: the one substep
/// rule, shared with the simulation's frame), and a guard that stops before
/// writing a non-finite or runaway state.
///
/// A step allocates nothing and never throws: it returns a StepResult.

#include <cstdint>

#include "common/fem/model.h"
#include "common/fem/state.h"

namespace cutsim::fem {

enum class ViscousTreatment {
  /// Damping force evaluated with the elastic one; the stable step includes
  /// the viscous limit (which shrinks ~h² and can dominate).
  kExplicit,
  /// Elastic step explicit, then the strain-rate damping by linearised
  /// backward Euler, (M + dt·C) v⁺ = M v*, C the damping operator at the
  /// current F, solved matrix-free by conjugate gradients with a block-Jacobi
  /// preconditioner (each free node's exact 3×3 diagonal block of M + dt·C,
  /// closed form per element: C_aa = vol·F[(φ+ψ)g gᵀ + ψ|g|²I]Fᵀ, g the
  /// node's row of Dm⁻ᵀ), warm-started from v* plus the previous step's
  /// correction v⁺ − v*, stopped at a residual relative to the right-hand
  /// side (StepOptions::cg_tolerance) or the iteration cap. Unconditionally
  /// stable: the exact solution has |v⁺|_M ≤ |v*|_M (multiply by v⁺ᵀ, C ⪰ 0),
  /// and a truncated iterate that would exceed |v*|_M is scaled back to it,
  /// so the viscous phase never adds kinetic energy; the stable step drops
  /// the viscous limit.
  kImplicit,
};

struct StepOptions {
  int num_threads = 0;  ///< OpenMP threads; 0 = omp_get_max_threads().
  ViscousTreatment viscous = ViscousTreatment::kExplicit;
  /// Implicit viscous: CG iteration cap (a capped solve is counted in
  /// StepResult::cg_capped and still dissipative, see kImplicit).
  int cg_max_iterations = 30;
  /// Implicit viscous: stop when |r|_P⁻¹ ≤ tol·|M v*|_P⁻¹ (P the block-Jacobi
  /// preconditioner), which bounds the velocity error of the step by about
  /// tol·|v*|_M. 1e-3 keeps a pressed and released ligament's trajectory
  /// within a small fraction of its displacement of a fully converged solve
  /// (tests/unit/fem/viscous_solve_test.cc checks the bound) at a few
  /// iterations a step, well inside the buffer model's 10% force budget.
  double cg_tolerance = 1e-3;
  /// Implicit viscous: start CG at v* + the last step's correction (else at v*).
  bool cg_warm_start = true;
  /// Implicit viscous: block-Jacobi preconditioner (else the mass matrix).
  bool cg_block_jacobi = true;
  /// Fraction of the estimated true stable limit used by Advance: the limit
  /// is the per-element bound × the Lanczos ratio (stable_dt.h) when
  /// spectral_iterations > 0, else the per-element bound alone (which is
  /// itself below the truth). 0.85 leaves a margin under the stress tests'
  /// limit of 1.0 (stable_dt.h).
  double safety_factor = 0.85;
  /// Fraction of the per-element bound used while the state is in a fast
  /// transient (the bound moved > 2% between its last refreshes, or > 10%
  /// since the Lanczos refresh), where the Lanczos ratio is not trusted:
  /// in violent releases variable-dt symplectic Euler pumps energy when the
  /// limit moves within the refresh interval, and the stress tests
  /// (stable_dt_test) need a step well under the bound, so 0.5.
  double transient_safety_factor = 0.5;
  int dt_refresh_interval = 10;   ///< Steps between per-element bound refreshes.
  /// Lanczos steps of the global estimate (0: per-element bound only).
  int spectral_iterations = 30;
  /// Steps between global (Lanczos) refreshes; also refreshed when the
  /// topology version changes. Each costs ~spectral_iterations force passes.
  int spectral_refresh_interval = 500;
  /// Mass-proportional (Rayleigh α) damping, 1/s: after the velocity update
  /// v ← v/(1 + α·dt) on free nodes — the implicit (backward Euler) solution
  /// of v̇ = −αv, so unconditionally stable, dissipative for any dt, and
  /// without effect on static equilibria (it only acts on velocity). Damps
  /// all modes at rate α (the low, slow ones that strain-rate damping barely
  /// touches), for fast relaxation to rest. 0 skips the work.
  double mass_damping = 0;
  double max_dt = 1e-3;           ///< Upper cap on a substep, s.
  /// Runaway guard: a free node faster than this stops the step, m/s.
  double max_speed = 1e3;
};

enum class StepStatus : uint8_t {
  kOk = 0,
  kNonFiniteForce,  ///< An element force was NaN/Inf (element set).
  kRunaway,         ///< A node would exceed max_speed or become NaN (node set).
  kBadTimeStep,     ///< dt not finite or ≤ 0.
  /// Implicit: no iterate of finite energy and residual, even in substeps
  /// (e.g. a nodal volume inverted at the start, where the barrier is +∞).
  /// Every value of the state is finite: it is the last completed step's.
  kNoAdmissibleIterate,
};

/// What a step did; on failure, which element/node, at which step, which
/// quantity and its value. The state is left as it was before the failing step.
struct StepResult {
  StepStatus status = StepStatus::kOk;
  int64_t step = 0;      ///< state.step at the failure (or after the last step).
  int32_t element = -1;  ///< Offending tet, if any.
  int32_t node = -1;     ///< Offending node, if any.
  const char* quantity = "";  ///< "element force", "speed", "dt", "implicit residual".
  double value = 0;      ///< The offending value (e.g. speed in m/s).
  int substeps = 0;      ///< Steps taken by Advance.
  double dt = 0;         ///< Last step size, s.
  /// Implicit viscous CG iterations (summed over Advance's substeps) and the
  /// solves among them that stopped at cg_max_iterations.
  int cg_iterations = 0;
  int cg_capped = 0;
  [[nodiscard]] bool ok() const { return status == StepStatus::kOk; }
};

/// One step of size dt. Requires !model.topology_dirty().
template <typename T>
StepResult Step(const Model<T>& model, State<T>& state, T dt, const StepOptions& options = {});

/// One substep of a frame: its size and whether it ends the frame.
struct Substep {
  double dt = 0;      ///< s
  bool last = false;  ///< the frame ends with this substep
};

/// The substep rule: the rest of a frame, `remaining` seconds, in equal
/// substeps no larger than `dt_max`, so the last one is not a sliver. Gives
/// the next one; a caller steps it, subtracts its dt from `remaining` and
/// stops after the `last` one.
[[nodiscard]] Substep EqualSubstep(double remaining, double dt_max);

/// Advances by `frame_time` in equal substeps (EqualSubstep) no larger than
/// the held step (CurrentTimeStep) and max_dt. Stops at the first failing
/// step.
template <typename T>
StepResult Advance(const Model<T>& model, State<T>& state, double frame_time,
                   const StepOptions& options = {});

/// The step Advance would take now (refreshes the bound if due), s.
/// The estimate is safety_factor × the Lanczos ratio × the per-element bound
/// when trusted (calm, the bound within 10% of its value at the Lanczos
/// refresh, and no single element's bound moved by more than 10% since:
/// State::dt_element_drift), else the transient factor × the bound; the
/// bound is refreshed every dt_refresh_interval steps and on topology
/// changes, so it follows stiffening under deformation. The step returned is
/// held (State::dt_held): 0.85 × the estimate when set, re-set at once when
/// the estimate falls below it, and only when the estimate grows by 20%
/// otherwise. Variable-step symplectic Euler is not symplectic: a step that
/// follows the estimate's wiggles with the oscillation pumps energy into
/// it (stability_test); a held step conserves it like a fixed one.
template <typename T>
T CurrentTimeStep(const Model<T>& model, State<T>& state, const StepOptions& options = {});

}  // namespace cutsim::fem
