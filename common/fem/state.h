#pragma once
/// @file
/// `fem::State<T>`: everything that changes during a step (MuJoCo's mjData
/// role): positions, velocities, forces, the caller's external force, and all
/// scratch, preallocated from the model's node capacity so Step never
/// allocates.

#include <cstdint>
#include <vector>

#include "common/fem/model.h"

namespace cutsim::fem {

template <typename T>
struct State {
  /// Sized for `model.node_capacity()`; x = rest positions, v = 0.
  explicit State(const Model<T>& model);

  std::vector<T> x;      ///< World positions, m.  // #N_cap×3
  std::vector<T> v;      ///< Velocities, m/s.  // #N_cap×3
  std::vector<T> f;      ///< Total nodal force of the last step, N.  // #N_cap×3
  /// External force, N (tool contact): the caller writes it before each
  /// step; the integrator only reads it.  // #N_cap×3
  std::vector<T> f_ext;
  double time = 0;       ///< Simulated time, s.
  int64_t step = 0;      ///< Steps taken.

  // ---- scratch (owned by the integrator; contents are undefined) ----------
  std::vector<T> element_force;  ///< Per-element nodal forces.  // #T_pad×12
  /// Nodal-pressure element: each node's pressure U'(J_a), Pa.  // #N_cap
  std::vector<T> node_pressure;
  std::vector<T> v_star;         ///< Implicit viscous: explicit predictor.  // #N_cap×3
  std::vector<T> cg_r, cg_p, cg_q;  ///< Implicit viscous CG vectors.  // #N_cap×3
  /// Implicit viscous: inverse of each node's 3×3 diagonal block of
  /// M + dt·C (block-Jacobi preconditioner), symmetric xx yy zz xy xz yz.  // #N_cap×6
  std::vector<T> cg_precond;
  /// When cg_precond was built: step, dt (s) and topology version. It is
  /// rebuilt every few steps, on a cut and when dt moves by more than 1 %
  /// (integrator.cc: a stale preconditioner costs iterations, not accuracy).
  int64_t cg_precond_step = -1;
  double cg_precond_dt = 0;
  uint64_t cg_precond_topology = 0;
  /// Implicit viscous: the last step's correction v⁺ − v* (the warm start of
  /// the next solve; not scratch: kept between steps, 0 initially).  // #N_cap×3
  std::vector<T> viscous_dv;

  // ---- stable time step ----------------------------------------------------
  /// Unscaled stable step bound per element (stable_dt.h), s.  // #T_pad
  std::vector<T> element_dt;
  /// Min tree over element_dt: leaves at [leaves, 2·leaves), root at 1.
  std::vector<T> dt_tree;
  int32_t dt_leaves = 0;
  int64_t dt_refreshed_step = -1;  ///< Step of the last full refresh.
  uint64_t dt_topology_version = 0;

  // ---- global (Lanczos) stable-step estimate, stable_dt.h ------------------
  /// Lanczos vectors and the perturbed positions of the finite-difference
  /// tangent.  // #N_cap×3 each
  std::vector<T> lanczos_prev, lanczos_q, lanczos_w, lanczos_x, lanczos_f0;
  /// Lanczos estimate of the true limit over the per-element bound, both at
  /// the last spectral refresh (≥ 1; 1 until the first refresh).
  double dt_ratio = 1.0;
  int64_t dt_spectral_step = -1;  ///< Step of the last spectral refresh.
  double dt_bound_at_spectral = 0;  ///< Per-element bound at that refresh, s.
  /// Every element's bound at the last spectral refresh, s.  // #T_pad
  std::vector<T> element_dt_at_spectral;
  /// Largest relative change of one element's bound since the spectral
  /// refresh, max_e |dt_e / dt_e(spectral) − 1|, at the last bound refresh.
  /// The global minimum can stay put while another element stiffens past
  /// it (a corner rattling under the tool), so the ratio is trusted only
  /// while this is small.
  double dt_element_drift = 0;
  /// The step Advance holds between estimate refreshes (0: none yet), s:
  /// 0.85 × the estimate when set, re-set at once when the estimate falls
  /// below it, and on growth only when the estimate is 20% above the one it
  /// was set from (integrator.cc: kDtHoldMargin, kDtGrowThreshold). A step that
  /// follows the estimate's every wiggle is variable-step symplectic Euler,
  /// which is not symplectic and pumps energy (integrator.h).
  double dt_held = 0;
  /// First step of the current run of estimates above the regrow threshold
  /// (−1: none); the held step grows only after dt_grow_delay steps of them.
  int64_t dt_grow_since = -1;
  int64_t dt_grow_delay = 0;       ///< Steps; backs off while the step toggles.
  int64_t dt_last_grow_step = -1;  ///< Step of the last growth (−1: undone or none).
  int dt_calm_refreshes = 0;  ///< Consecutive bound refreshes that changed it ≤ 2%.
  bool dt_trusted = false;    ///< Whether the last CurrentTimeStep used the ratio.
  uint64_t dt_spectral_topology_version = 0;
};

extern template struct State<float>;
extern template struct State<double>;

}  // namespace cutsim::fem
