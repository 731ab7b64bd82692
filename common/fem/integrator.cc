#include "common/fem/integrator.h"

#include <omp.h>

#include <algorithm>
#include <climits>
#include <cmath>

#include "common/core/error.h"
#include "common/fem/forces.h"
#include "common/fem/node_sums.h"
#include "common/fem/stable_dt.h"
#include "common/fem/threads.h"

namespace cutsim::fem {

namespace {

// Step-size policy of Advance (State::dt_held): the held step is this
// fraction of the estimate when set, and is re-set when the estimate falls
// below it or exceeds it by this factor.
constexpr double kDtHoldMargin = 0.85;
constexpr double kDtGrowThreshold = 1.2 / 0.85;
// Back-off of the held step's regrowth (CurrentTimeStep): a growth undone
// within kDtToggleWindow steps doubles the delay (from kDtGrowDelayMin, at
// most kDtGrowDelayMax steps); one that lasts halves it.
constexpr int64_t kDtToggleWindow = 2000;
constexpr int64_t kDtGrowDelayMin = 64;
constexpr int64_t kDtGrowDelayMax = 4096;

// Steps between rebuilds of the viscous CG's block-Jacobi preconditioner.
constexpr int64_t kPrecondRefreshSteps = 10;

/// Block-Jacobi preconditioner of M + dt·C: for each free node the inverse
/// of m·I + dt·Σ_e C_aa, with C_aa = vol·F[(φ+ψ)g gᵀ + ψ|g|²I]Fᵀ the damping
/// force on node a per unit velocity of node a (Ḟ = u gᵀ, g = row of Dm⁻ᵀ
/// for the node's corner, −Σ of the others for corner 0). Stored symmetric:
/// xx yy zz xy xz yz. Fixed nodes get 0 (they are held at zero velocity).
template <typename T>
void BuildBlockJacobi(const Model<T>& model, const T* x, T dt, bool with_damping, T* inv, int nt) {
  const int32_t nn = model.num_nodes();
  const T* mass = model.node_masses();
  const uint8_t* fixed = model.fixed_mask();
  const int32_t* range = model.incidence_ranges();
  const int32_t* slots = model.incidence_slots();
  const int32_t* tets = model.tets();
  const T* vol = model.rest_volumes();
  const T* psi = model.psis();
  const T* phi = model.phis();
  const T* b[9];
  for (int k = 0; k < 9; ++k) b[k] = model.dm_inv(k);
#pragma omp parallel for schedule(static) num_threads(nt)
  for (int32_t n = 0; n < nn; ++n) {
    T* out = inv + 6 * n;
    if (fixed[n] != 0 || !(mass[n] > T(0))) {
      for (int k = 0; k < 6; ++k) out[k] = 0;
      continue;
    }
    // A = m·I + dt·Σ C_aa (symmetric, accumulated in T).
    T a00 = mass[n], a11 = mass[n], a22 = mass[n], a01 = 0, a02 = 0, a12 = 0;
    const int32_t k_end = with_damping ? range[2 * n + 1] : range[2 * n];  // else P = M
    for (int32_t k = range[2 * n]; k < k_end; ++k) {
      const int32_t t = slots[k] / 12;
      const int corner = (slots[k] % 12) / 3;
      const int32_t* tn = tets + 4 * t;
      const T* x0 = x + 3 * tn[0];
      T B[9], F[9], g[3];
      for (int i = 0; i < 9; ++i) B[i] = b[i][t];
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) {
          F[3 * r + c] = (x[3 * tn[1] + r] - x0[r]) * B[c] + (x[3 * tn[2] + r] - x0[r]) * B[3 + c] +
                         (x[3 * tn[3] + r] - x0[r]) * B[6 + c];
        }
      }
      for (int c = 0; c < 3; ++c) {
        g[c] = corner > 0 ? B[3 * (corner - 1) + c] : -(B[c] + B[3 + c] + B[6 + c]);
      }
      // h = F g (3), C_aa = vol·[(φ+ψ) h hᵀ + ψ|g|² F Fᵀ].
      T h[3], fft[6];
      for (int r = 0; r < 3; ++r) h[r] = F[3 * r] * g[0] + F[3 * r + 1] * g[1] + F[3 * r + 2] * g[2];
      const auto row_dot = [&](int i, int j) {
        return F[3 * i] * F[3 * j] + F[3 * i + 1] * F[3 * j + 1] + F[3 * i + 2] * F[3 * j + 2];
      };
      fft[0] = row_dot(0, 0), fft[1] = row_dot(1, 1), fft[2] = row_dot(2, 2);
      fft[3] = row_dot(0, 1), fft[4] = row_dot(0, 2), fft[5] = row_dot(1, 2);
      const T s1 = dt * vol[t] * (phi[t] + psi[t]);
      const T s2 = dt * vol[t] * psi[t] * (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
      a00 += s1 * h[0] * h[0] + s2 * fft[0];
      a11 += s1 * h[1] * h[1] + s2 * fft[1];
      a22 += s1 * h[2] * h[2] + s2 * fft[2];
      a01 += s1 * h[0] * h[1] + s2 * fft[3];
      a02 += s1 * h[0] * h[2] + s2 * fft[4];
      a12 += s1 * h[1] * h[2] + s2 * fft[5];
    }
    // Inverse by cofactors: A = m·I + PSD, so det ≥ m³ > 0.
    const T c00 = a11 * a22 - a12 * a12, c01 = a02 * a12 - a01 * a22, c02 = a01 * a12 - a02 * a11;
    const T c11 = a00 * a22 - a02 * a02, c12 = a01 * a02 - a00 * a12, c22 = a00 * a11 - a01 * a01;
    const T det = a00 * c00 + a01 * c01 + a02 * c02;
    const T id = det > T(0) && std::isfinite(det) ? T(1) / det : T(0);
    if (id > T(0)) {
      out[0] = c00 * id, out[1] = c11 * id, out[2] = c22 * id;
      out[3] = c01 * id, out[4] = c02 * id, out[5] = c12 * id;
    } else {  // non-finite F: fall back to M⁻¹ (the CG then breaks down and the guard keeps v* safe)
      out[0] = out[1] = out[2] = T(1) / mass[n];
      out[3] = out[4] = out[5] = 0;
    }
  }
}

/// z = P⁻¹ r for one node's symmetric 3×3 block.
template <typename T>
inline void ApplyBlock(const T* p, const T* r, T* z) {
  z[0] = p[0] * r[0] + p[3] * r[1] + p[4] * r[2];
  z[1] = p[3] * r[0] + p[1] * r[1] + p[5] * r[2];
  z[2] = p[4] * r[0] + p[5] * r[1] + p[2] * r[2];
}

/// q = (M + dt·C) p on free DOFs (0 on fixed ones); returns pᵀq. C·p =
/// −f_visc(p), linear in p at the current F. `*bad` as ElementForcesTeam.
template <typename T>
double ApplyViscousSystem(const Model<T>& model, const T* x, const T* p, T dt, T* ef, T* q, int32_t* bad,
                          int nt) {
  const int32_t nn = model.num_nodes();
  const T* mass = model.node_masses();
  const uint8_t* fixed = model.fixed_mask();
  NodeSums<1> pq(nn);  // the same bits for any thread count (node_sums.h)
#pragma omp parallel num_threads(nt)
  {
    ElementForcesTeam<T>(model, x, p, ForceMode::kViscousOnly, nullptr, ef, bad);
#pragma omp barrier
    GatherNodeForcesTeam<T>(model, ef, nullptr, false, q);  // q = f_visc(p) = −C p
    pq.Team([&](int32_t n, std::array<double, 1>& acc) {
      const bool active = fixed[n] == 0 && mass[n] > T(0);
      for (int d = 0; d < 3; ++d) {
        const T qd = active ? mass[n] * p[3 * n + d] - dt * q[3 * n + d] : T(0);
        q[3 * n + d] = qd;
        acc[0] += static_cast<double>(p[3 * n + d] * qd);
      }
    });
  }
  return pq.Total(0);
}

/// Implicit viscous update (ViscousTreatment::kImplicit): solves
/// (M + dt·C) v⁺ = M v* on the free nodes by block-Jacobi-preconditioned CG,
/// warm-started at v* + (the last step's v⁺ − v*). On entry state.v holds
/// v*; on exit v⁺. Returns the iteration count; *capped when it stopped at
/// the cap.
template <typename T>
int ImplicitViscous(const Model<T>& model, State<T>& state, T dt, const StepOptions& opt, int nt,
                    bool* capped) {
  const int32_t nn = model.num_nodes();
  const T* mass = model.node_masses();
  const uint8_t* fixed = model.fixed_mask();
  T* sol = state.v.data();
  T* vs = state.v_star.data();
  T* dv = state.viscous_dv.data();
  T* r = state.cg_r.data();
  T* p = state.cg_p.data();
  T* q = state.cg_q.data();
  T* pre = state.cg_precond.data();
  T* ef = state.element_force.data();
  const T* x = state.x.data();
  *capped = false;
  // The preconditioner only steers CG (the tolerance sets the accuracy), so
  // it is reused while the state moves little: building it costs about one
  // system product, a sizeable part of a step that takes a few iterations.
  if (state.cg_precond_step < 0 || state.step < state.cg_precond_step ||
      state.step - state.cg_precond_step >= kPrecondRefreshSteps ||
      state.cg_precond_topology != model.topology_version() ||
      std::abs(static_cast<double>(dt) / state.cg_precond_dt - 1.0) > 0.01) {
    BuildBlockJacobi(model, x, dt, opt.cg_block_jacobi, pre, nt);
    state.cg_precond_step = state.step;
    state.cg_precond_dt = static_cast<double>(dt);
    state.cg_precond_topology = model.topology_version();
  }
  const T warm = opt.cg_warm_start ? T(1) : T(0);
  // v* aside; the start sol = v* + dv; bb = |M v*|²_P⁻¹ (the scale of the
  // residual), e_star = |v*|²_M (the energy bound of the solution).
  // Every sum of the solve gives the same bits for any thread count
  // (node_sums.h): α, β and the stopping test steer the iterate.
  NodeSums<2> start_sums(nn);
#pragma omp parallel num_threads(nt)
  start_sums.Team([&](int32_t n, std::array<double, 2>& acc) {
    const bool active = fixed[n] == 0 && mass[n] > T(0);
    T b[3], z[3];
    for (int d = 0; d < 3; ++d) {
      const int32_t i = 3 * n + d;
      // Fixed nodes are held at zero velocity inside the solve; their own
      // velocity waits in dv (unused for them) and is put back at the end.
      if (!active) dv[i] = sol[i];
      vs[i] = active ? sol[i] : T(0);
      sol[i] = active ? vs[i] + warm * dv[i] : T(0);
      b[d] = mass[n] * vs[i];
    }
    ApplyBlock(pre + 6 * n, b, z);
    for (int d = 0; d < 3; ++d) {
      acc[0] += static_cast<double>(b[d] * z[d]);
      acc[1] += static_cast<double>(b[d] * vs[3 * n + d]);
    }
  });
  const double bb = start_sums.Total(0), e_star = start_sums.Total(1);
  int iterations = 0;
  if (!(bb > 0)) {
    // v* = 0 on every free node: the solution is 0.
#pragma omp parallel for schedule(static) num_threads(nt)
    for (int32_t n = 0; n < nn; ++n) {
      const bool active = fixed[n] == 0 && mass[n] > T(0);
      for (int d = 0; d < 3; ++d) {
        sol[3 * n + d] = active ? T(0) : dv[3 * n + d];
        if (active) dv[3 * n + d] = 0;
      }
    }
    return 0;
  }
  const double tol2 = opt.cg_tolerance * opt.cg_tolerance * bb;
  // r = M v* − A sol, p = z = P⁻¹ r.
  int32_t bad = INT32_MAX;
  (void)ApplyViscousSystem(model, x, sol, dt, ef, q, &bad, nt);
  NodeSums<1> rz_sum(nn);
#pragma omp parallel num_threads(nt)
  rz_sum.Team([&](int32_t n, std::array<double, 1>& acc) {
    for (int d = 0; d < 3; ++d) r[3 * n + d] = mass[n] * vs[3 * n + d] - q[3 * n + d];
    ApplyBlock(pre + 6 * n, r + 3 * n, p + 3 * n);
    for (int d = 0; d < 3; ++d) acc[0] += static_cast<double>(r[3 * n + d] * p[3 * n + d]);
  });
  double rz = rz_sum.Total(0);
  bool converged = bad == INT32_MAX && rz <= tol2;
  while (!converged && bad == INT32_MAX && iterations < opt.cg_max_iterations) {
    const double pq = ApplyViscousSystem(model, x, p, dt, ef, q, &bad, nt);
    if (!(pq > 0) || bad != INT32_MAX) break;  // breakdown: keep the iterate (clamped below)
    ++iterations;
    const T alpha = static_cast<T>(rz / pq);
    NodeSums<1> rz_new_sum(nn);
#pragma omp parallel num_threads(nt)
    rz_new_sum.Team([&](int32_t n, std::array<double, 1>& acc) {
      T z[3];
      for (int d = 0; d < 3; ++d) {
        const int32_t i = 3 * n + d;
        sol[i] += alpha * p[i];
        r[i] -= alpha * q[i];
      }
      ApplyBlock(pre + 6 * n, r + 3 * n, z);
      for (int d = 0; d < 3; ++d) acc[0] += static_cast<double>(r[3 * n + d] * z[d]);
    });
    const double rz_new = rz_new_sum.Total(0);
    if (rz_new <= tol2) {
      converged = true;
      break;
    }
    const T beta = static_cast<T>(rz_new / rz);
    rz = rz_new;
#pragma omp parallel for schedule(static) num_threads(nt)
    for (int32_t n = 0; n < nn; ++n) {
      T z[3];
      ApplyBlock(pre + 6 * n, r + 3 * n, z);
      for (int d = 0; d < 3; ++d) p[3 * n + d] = z[d] + beta * p[3 * n + d];
    }
  }
  *capped = !converged;
  // The exact solution has |v⁺|_M ≤ |v*|_M; a truncated (warm-started)
  // iterate may not, so scale it back: the viscous phase never adds energy.
  NodeSums<1> e_sol_sum(nn);
#pragma omp parallel num_threads(nt)
  e_sol_sum.Team([&](int32_t n, std::array<double, 1>& acc) {
    for (int d = 0; d < 3; ++d) acc[0] += static_cast<double>(mass[n] * sol[3 * n + d] * sol[3 * n + d]);
  });
  const double e_sol = e_sol_sum.Total(0);
  const T scale = !std::isfinite(e_sol) ? T(0)
                  : e_sol > e_star     ? static_cast<T>(std::sqrt(e_star / e_sol))
                                       : T(1);
#pragma omp parallel for schedule(static) num_threads(nt)
  for (int32_t n = 0; n < nn; ++n) {
    const bool active = fixed[n] == 0 && mass[n] > T(0);
    for (int d = 0; d < 3; ++d) {
      const int32_t i = 3 * n + d;
      if (!active) {
        sol[i] = dv[i];
        continue;
      }
      sol[i] = scale == T(0) ? T(0) : sol[i] * scale;  // 0 also clears a NaN
      dv[i] = sol[i] - vs[i];
    }
  }
  return iterations;
}

}  // namespace

template <typename T>
StepResult Step(const Model<T>& model, State<T>& state, T dt, const StepOptions& options) {
  CUTSIM_CHECK(!model.topology_dirty(), "fem::Step: call Model::CommitTopology after mutations");
  StepResult res;
  res.step = state.step;
  res.dt = static_cast<double>(dt);
  if (!(dt > T(0)) || !std::isfinite(dt)) {
    res.status = StepStatus::kBadTimeStep;
    res.quantity = "dt";
    res.value = static_cast<double>(dt);
    return res;
  }
  const int nt = Threads(options.num_threads);
  const bool implicit_visc = model.damped() && options.viscous == ViscousTreatment::kImplicit;
  const ForceMode mode =
      model.damped() && !implicit_visc ? ForceMode::kElasticDamped : ForceMode::kElastic;
  const int32_t nn = model.num_nodes();
  const T* mass = model.node_masses();
  const uint8_t* fixed = model.fixed_mask();
  T* x = state.x.data();
  T* v = state.v.data();
  T* f = state.f.data();
  T* ef = state.element_force.data();
  const T max_v2 = static_cast<T>(options.max_speed * options.max_speed);
  // Rayleigh α (mass-proportional) damping, backward Euler: v ← v/(1 + α·dt).
  const bool mass_damped = options.mass_damping > 0;
  const T mass_damp_scale = static_cast<T>(1.0 / (1.0 + options.mass_damping * static_cast<double>(dt)));

  int32_t bad_tet = INT32_MAX;
  int runaway = 0;
#pragma omp parallel num_threads(nt)
  {
    ElementForcesTeam(model, x, v, mode, state.node_pressure.data(), ef, &bad_tet);
#pragma omp barrier
    GatherNodeForcesTeam<T>(model, ef, state.f_ext.data(), true, f);
    // Guard before writing anything: the predicted velocity of every free
    // node must be finite and below max_speed (a NaN fails `<=` too).
#pragma omp for schedule(static) reduction(| : runaway)
    for (int32_t n = 0; n < nn; ++n) {
      if (fixed[n] != 0 || !(mass[n] > T(0))) continue;
      const T h = dt / mass[n];
      const T a = v[3 * n] + h * f[3 * n];
      const T b = v[3 * n + 1] + h * f[3 * n + 1];
      const T c = v[3 * n + 2] + h * f[3 * n + 2];
      runaway |= !(a * a + b * b + c * c <= max_v2) ? 1 : 0;
    }
    // All threads read the same flags after the reduction's barrier.
    if (bad_tet == INT32_MAX && runaway == 0) {
#pragma omp for schedule(static)
      for (int32_t n = 0; n < nn; ++n) {
        if (fixed[n] != 0 || !(mass[n] > T(0))) continue;
        const T h = dt / mass[n];
        for (int d = 0; d < 3; ++d) v[3 * n + d] += h * f[3 * n + d];
        if (mass_damped) {
          for (int d = 0; d < 3; ++d) v[3 * n + d] *= mass_damp_scale;
        }
        if (!implicit_visc) {
          for (int d = 0; d < 3; ++d) x[3 * n + d] += dt * v[3 * n + d];
        }
      }
    }
  }
  if (bad_tet != INT32_MAX) [[unlikely]] {
    res.status = StepStatus::kNonFiniteForce;
    res.element = bad_tet;
    res.quantity = "element force";
    res.value = std::nan("");
    return res;
  }
  if (runaway != 0) [[unlikely]] {
    double worst = -1;
    for (int32_t n = 0; n < nn; ++n) {
      if (fixed[n] != 0 || !(mass[n] > T(0))) continue;
      double s2 = 0;
      for (int d = 0; d < 3; ++d) {
        const double vd = static_cast<double>(v[3 * n + d] + dt / mass[n] * f[3 * n + d]);
        s2 += vd * vd;
      }
      if (!(s2 <= worst)) {  // NaN wins
        worst = s2;
        res.node = n;
        if (std::isnan(s2)) break;
      }
    }
    res.status = StepStatus::kRunaway;
    res.quantity = "speed";
    res.value = std::sqrt(worst);
    return res;
  }
  if (implicit_visc) {
    // state.v holds v* = v + dt·M⁻¹f_elastic; damp it implicitly, then move.
    bool capped = false;
    res.cg_iterations = ImplicitViscous(model, state, dt, options, nt, &capped);
    res.cg_capped = capped ? 1 : 0;
#pragma omp parallel for schedule(static) num_threads(nt)
    for (int32_t n = 0; n < nn; ++n) {
      if (fixed[n] != 0 || !(mass[n] > T(0))) continue;
      for (int d = 0; d < 3; ++d) x[3 * n + d] += dt * v[3 * n + d];
    }
  }
  ++state.step;
  state.time += static_cast<double>(dt);
  res.step = state.step;
  return res;
}

template <typename T>
T CurrentTimeStep(const Model<T>& model, State<T>& state, const StepOptions& options) {
  const bool explicit_visc = options.viscous == ViscousTreatment::kExplicit || !model.damped();
  if (options.spectral_iterations <= 0) {
    state.dt_ratio = 1.0;
  } else if (state.dt_spectral_step >= 0 && state.dt_spectral_topology_version != model.topology_version()) {
    // A cut changed the mesh: fall back to the provably safe bound at once
    // (no Lanczos cost inside the cut frame) and re-estimate soon.
    state.dt_ratio = 1.0;
    state.dt_spectral_topology_version = model.topology_version();
    state.dt_spectral_step =
        std::min(state.dt_spectral_step,
                 state.step - options.spectral_refresh_interval + std::min(options.spectral_refresh_interval, 100));
  } else if (state.dt_spectral_step < 0 ||
             state.step - state.dt_spectral_step >= options.spectral_refresh_interval) {
    RefreshSpectralRatio(model, state, explicit_visc, options.spectral_iterations, options.num_threads);
  }
  if (state.dt_refreshed_step < 0 || state.step - state.dt_refreshed_step >= options.dt_refresh_interval ||
      state.dt_topology_version != model.topology_version()) {
    const bool had = state.dt_refreshed_step >= 0 && state.dt_topology_version == model.topology_version();
    const double before = had ? static_cast<double>(StableStepBound(state)) : 0.0;
    RefreshStableStep(model, state, explicit_visc, options.num_threads);
    const double after = static_cast<double>(StableStepBound(state));
    const bool calm = had && std::abs(after / before - 1.0) <= 0.02;
    state.dt_calm_refreshes = calm ? state.dt_calm_refreshes + 1 : 0;
  }
  // The Lanczos ratio is used only in a calm state close to where it was
  // measured (stable_dt.h); otherwise the transient factor of the bound.
  const double bound = static_cast<double>(StableStepBound(state));
  state.dt_trusted = options.spectral_iterations > 0 && state.dt_ratio > 1.0 && state.dt_calm_refreshes >= 10 &&
                     std::abs(bound / state.dt_bound_at_spectral - 1.0) <= 0.1 && state.dt_element_drift <= 0.1;
  if (options.spectral_iterations > 0 && !state.dt_trusted && state.dt_calm_refreshes >= 10 &&
      state.dt_spectral_step >= 0 && state.step - state.dt_spectral_step >= options.spectral_refresh_interval / 10) {
    // Calm again far from the last estimate: re-estimate now.
    RefreshSpectralRatio(model, state, explicit_visc, options.spectral_iterations, options.num_threads);
    state.dt_trusted = state.dt_ratio > 1.0;
  }
  const double factor = state.dt_trusted ? options.safety_factor * state.dt_ratio
                                         : std::min(options.safety_factor, options.transient_safety_factor);
  const double estimate = factor * static_cast<double>(StableStepBound(state));
  // Hold the step between refreshes (State::dt_held): shrink at once; grow
  // only past the dead band and after the estimate has stayed there for
  // dt_grow_delay steps. The delay backs off (×2, up to kDtGrowDelayMax)
  // whenever a growth is undone within kDtToggleWindow steps, and decays
  // (÷2) when one lasts: a step that toggles with the phase of an
  // oscillation (the trust in the Lanczos ratio flipping with the element
  // drift) pumps energy into it, while a step that drops at a cut or a
  // contact should come back at once. Only for an undamped model: with
  // damping the pumping is dissipated, and the back-off would cost damped
  // scenes with contact and cuts many more steps.
  const bool conservative = !model.damped() && !(options.mass_damping > 0);
  if (!(state.dt_held > 0) || !(estimate >= state.dt_held)) {
    if (conservative && state.dt_held > 0 && state.dt_last_grow_step >= 0) {
      state.dt_grow_delay = state.step - state.dt_last_grow_step < kDtToggleWindow
                                ? std::min<int64_t>(std::max<int64_t>(2 * state.dt_grow_delay, kDtGrowDelayMin), kDtGrowDelayMax)
                                : state.dt_grow_delay / 2;
      state.dt_last_grow_step = -1;
    }
    state.dt_held = kDtHoldMargin * estimate;
    state.dt_grow_since = -1;
  } else if (estimate > kDtGrowThreshold * state.dt_held) {
    if (state.dt_grow_since < 0) state.dt_grow_since = state.step;
    if (state.step - state.dt_grow_since >= state.dt_grow_delay) {
      state.dt_held = kDtHoldMargin * estimate;
      state.dt_grow_since = -1;
      state.dt_last_grow_step = state.step;
    }
  } else {
    state.dt_grow_since = -1;
  }
  return std::min(static_cast<T>(state.dt_held), static_cast<T>(options.max_dt));
}

Substep EqualSubstep(double remaining, double dt_max) {
  // The count of steps left, less a hair so that round-off in `remaining`
  // does not add a sliver step.
  const double n = std::ceil(remaining / dt_max * (1.0 - 1e-12));
  return {.dt = remaining / std::max(1.0, n), .last = n <= 1};
}

template <typename T>
StepResult Advance(const Model<T>& model, State<T>& state, double frame_time,
                   const StepOptions& options) {
  StepResult res;
  res.step = state.step;
  double remaining = frame_time;
  while (remaining > 0) {
    const Substep sub = EqualSubstep(remaining, static_cast<double>(CurrentTimeStep(model, state, options)));
    const int substeps = res.substeps;
    const int cg_iterations = res.cg_iterations;
    const int cg_capped = res.cg_capped;
    res = Step(model, state, static_cast<T>(sub.dt), options);
    res.substeps = substeps + (res.ok() ? 1 : 0);
    res.cg_iterations += cg_iterations;
    res.cg_capped += cg_capped;
    if (!res.ok()) return res;
    remaining -= sub.dt;
    if (sub.last) break;
  }
  return res;
}

#define CUTSIM_FEM_INSTANTIATE(T)                                                              \
  template StepResult Step<T>(const Model<T>&, State<T>&, T, const StepOptions&);             \
  template StepResult Advance<T>(const Model<T>&, State<T>&, double, const StepOptions&);     \
  template T CurrentTimeStep<T>(const Model<T>&, State<T>&, const StepOptions&);

CUTSIM_FEM_INSTANTIATE(float)
CUTSIM_FEM_INSTANTIATE(double)
#undef CUTSIM_FEM_INSTANTIATE

}  // namespace cutsim::fem
