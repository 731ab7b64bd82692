#include "common/fem/integrator.h"

#include <omp.h>

#include <algorithm>
#include <climits>
#include <cmath>

#include "common/core/error.h"
#include "common/fem/forces.h"
#include "common/fem/stable_dt.h"

namespace cutsim::fem {

namespace {

int Threads(int requested) { return requested > 0 ? requested : omp_get_max_threads(); }

/// Implicit viscous update: solves (M + dt·C) v = M v* on the free nodes by
/// M-preconditioned CG from v = 0, where C·p = −f_visc(p) (linear in p at the
/// current F; fixed nodes are held at zero velocity inside the solve).
/// On entry state.v holds v*; on exit the solution.
template <typename T>
void ImplicitViscous(const Model<T>& model, State<T>& state, T dt, const StepOptions& opt,
                     int nt) {
  const int32_t nn = model.num_nodes();
  const T* mass = model.node_masses();
  const uint8_t* fixed = model.fixed_mask();
  T* sol = state.v.data();
  T* r = state.cg_r.data();
  T* p = state.cg_p.data();
  T* q = state.cg_q.data();
  T* ef = state.element_force.data();
  const T* x = state.x.data();
  double rz = 0;
  // r = M v*, z = M⁻¹r = v*, p = z, sol = 0.
#pragma omp parallel for schedule(static) num_threads(nt) reduction(+ : rz)
  for (int32_t n = 0; n < nn; ++n) {
    const bool active = fixed[n] == 0 && mass[n] > T(0);
    for (int d = 0; d < 3; ++d) {
      const T vs = active ? sol[3 * n + d] : T(0);
      r[3 * n + d] = mass[n] * vs;
      p[3 * n + d] = vs;
      rz += static_cast<double>(mass[n] * vs * vs);
      if (active) sol[3 * n + d] = 0;
    }
  }
  const double rz0 = rz;
  if (!(rz0 > 0)) {
    return;  // nothing moves (v* = 0): the solution is 0 on free nodes, already set
  }
  const double tol2 = opt.cg_tolerance * opt.cg_tolerance * rz0;
  for (int it = 0; it < opt.cg_max_iterations; ++it) {
    double pq = 0;
    int32_t bad = INT32_MAX;
#pragma omp parallel num_threads(nt)
    {
      ElementForcesTeam(model, x, p, ForceMode::kViscousOnly, ef, &bad);
#pragma omp barrier
      GatherNodeForcesTeam<T>(model, ef, nullptr, false, q);  // q = f_visc(p) = −C p
#pragma omp for schedule(static) reduction(+ : pq)
      for (int32_t n = 0; n < nn; ++n) {
        const bool active = fixed[n] == 0 && mass[n] > T(0);
        for (int d = 0; d < 3; ++d) {
          // q = (M + dt·C) p on free DOFs.
          const T qd = active ? mass[n] * p[3 * n + d] - dt * q[3 * n + d] : T(0);
          q[3 * n + d] = qd;
          pq += static_cast<double>(p[3 * n + d] * qd);
        }
      }
    }
    if (!(pq > 0) || bad != INT32_MAX) break;  // breakdown: keep the last (dissipative) iterate
    const T alpha = static_cast<T>(rz / pq);
    double rz_new = 0;
#pragma omp parallel for schedule(static) num_threads(nt) reduction(+ : rz_new)
    for (int32_t n = 0; n < nn; ++n) {
      const T inv_m = mass[n] > T(0) ? T(1) / mass[n] : T(0);
      for (int d = 0; d < 3; ++d) {
        const int32_t i = 3 * n + d;
        sol[i] += alpha * p[i];
        r[i] -= alpha * q[i];
        rz_new += static_cast<double>(r[i] * r[i] * inv_m);
      }
    }
    if (rz_new <= tol2) break;
    const T beta = static_cast<T>(rz_new / rz);
    rz = rz_new;
#pragma omp parallel for schedule(static) num_threads(nt)
    for (int32_t n = 0; n < nn; ++n) {
      const T inv_m = mass[n] > T(0) ? T(1) / mass[n] : T(0);
      for (int d = 0; d < 3; ++d) p[3 * n + d] = r[3 * n + d] * inv_m + beta * p[3 * n + d];
    }
  }
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
    ElementForcesTeam(model, x, v, mode, ef, &bad_tet);
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
    ImplicitViscous(model, state, dt, options, nt);
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
                     std::abs(bound / state.dt_bound_at_spectral - 1.0) <= 0.1;
  if (options.spectral_iterations > 0 && !state.dt_trusted && state.dt_calm_refreshes >= 10 &&
      state.dt_spectral_step >= 0 && state.step - state.dt_spectral_step >= options.spectral_refresh_interval / 10) {
    // Calm again far from the last estimate: re-estimate now.
    RefreshSpectralRatio(model, state, explicit_visc, options.spectral_iterations, options.num_threads);
    state.dt_trusted = state.dt_ratio > 1.0;
  }
  const double factor = state.dt_trusted ? options.safety_factor * state.dt_ratio
                                         : std::min(options.safety_factor, options.transient_safety_factor);
  return std::min(static_cast<T>(factor * static_cast<double>(StableStepBound(state))),
                  static_cast<T>(options.max_dt));
}

template <typename T>
StepResult Advance(const Model<T>& model, State<T>& state, double frame_time,
                   const StepOptions& options) {
  StepResult res;
  res.step = state.step;
  double remaining = frame_time;
  while (remaining > 0) {
    const double dt_max = static_cast<double>(CurrentTimeStep(model, state, options));
    // Equal substeps for the rest of the frame, so the last one is not a sliver.
    const double n = std::ceil(remaining / dt_max * (1.0 - 1e-12));
    const double dt = remaining / std::max(1.0, n);
    const int substeps = res.substeps;
    res = Step(model, state, static_cast<T>(dt), options);
    res.substeps = substeps + (res.ok() ? 1 : 0);
    if (!res.ok()) return res;
    remaining -= dt;
    if (n <= 1) break;
  }
  return res;
}

#define CUTSIM_FEM_INSTANTIATE(T)                                                              \
  template StepResult Step<T>(const Model<T>&, State<T>&, T, const StepOptions&);             \
  template StepResult Advance<T>(const Model<T>&, State<T>&, double, const StepOptions&);     \
  template T CurrentTimeStep<T>(const Model<T>&, State<T>&, const StepOptions&);

CUTSIM_FEM_INSTANTIATE(float)
CUTSIM_FEM_INSTANTIATE(double)

}  // namespace cutsim::fem
