#include "common/fem/stable_dt.h"

#include <omp.h>

#include <algorithm>
#include <climits>
#include <utility>
#include <cmath>
#include <limits>

#include "common/fem/forces.h"
#include "common/fem/node_sums.h"

namespace cutsim::fem {

template <typename T>
T ElementStableStep(const Model<T>& model, const T* x, int32_t t, bool explicit_viscous) {
  const T vol = model.rest_volume(t);
  const T m = model.element_mass(t) / T(4);
  if (!(vol > T(0)) || !(m > T(0))) return std::numeric_limits<T>::infinity();
  const Mat3<T> F = DeformationGradient(model, x, t);
  const Mat3<T> C = F.transpose() * F;
  // ≥ σ_max(F)², floored at the rest value 1: a compressed element is softer
  // now but re-stiffens within the step interval as it springs back, so a
  // compressed state must never buy a longer step (measured: without the
  // floor, a body released from compression blows up at 0.5 of the bound).
  const T s2 = std::max(T(1), GershgorinMax<T>(C));
  const T mu = model.mus()[t];
  T lam = model.lambdas()[t];
  if (model.element() == ElementKind::kNodalPressure) {
    // The nodal bulk stiffness U''(J) = κ/2·(1 + 1/J²) exceeds κ under
    // compression; the element's own J stands in for its nodes'.
    const T j = std::max(F.determinant(), T(0.027));
    lam *= std::max(T(1), T(0.5) * (T(1) + T(1) / (j * j)));
  }
  const Mat3<T> S = StvkSecondPiola<T>(T(0.5) * (C - Mat3<T>::Identity()), lam, mu);
  const T k = std::max(T(0), GershgorinMax<T>(S)) + std::max(T(3) * lam + T(2) * mu, T(2) * mu) * s2;
  const T g = model.grad_sq_max(t);
  const T omega2 = vol * k * g / m;
  T c = 0;
  if (explicit_viscous) {
    const T psi = model.psis()[t], phi = model.phis()[t];
    c = vol * std::max(T(3) * phi + T(2) * psi, T(2) * psi) * s2 * g / m;
  }
  return T(4) / (c + std::sqrt(c * c + T(4) * omega2));
}

namespace {

template <typename T>
void SetLeaf(State<T>& state, int32_t t, T value) {
  state.element_dt[static_cast<size_t>(t)] = value;
  size_t i = static_cast<size_t>(state.dt_leaves + t);
  state.dt_tree[i] = value;
  for (i /= 2; i >= 1; i /= 2) {
    const T m = std::min(state.dt_tree[2 * i], state.dt_tree[2 * i + 1]);
    if (state.dt_tree[i] == m) break;  // nothing above changes
    state.dt_tree[i] = m;
  }
}

}  // namespace

template <typename T>
void RefreshStableStep(const Model<T>& model, State<T>& state, bool explicit_viscous,
                       int num_threads) {
  const int32_t nt = model.num_tets();
  const T* x = state.x.data();
  T* leaves = state.dt_tree.data() + state.dt_leaves;
  T* elem = state.element_dt.data();
  const T* at_spectral = state.element_dt_at_spectral.data();
  double drift = 0;
#pragma omp parallel num_threads(num_threads > 0 ? num_threads : omp_get_max_threads())
  {
#pragma omp for schedule(static) reduction(max : drift)
    for (int32_t t = 0; t < nt; ++t) {
      const T dt = ElementStableStep(model, x, t, explicit_viscous);
      elem[t] = dt;
      leaves[t] = dt;
      // Relative change since the spectral refresh (inert elements: none;
      // an element that appeared or changed state: +∞, i.e. not trusted).
      const double now = static_cast<double>(dt), then = static_cast<double>(at_spectral[t]);
      if (std::isfinite(now) || std::isfinite(then)) {
        const double change = std::isfinite(now) && std::isfinite(then) && then > 0
                                  ? std::abs(now / then - 1.0)
                                  : std::numeric_limits<double>::infinity();
        drift = std::max(drift, change);
      }
    }
  }
  state.dt_element_drift = drift;
  for (int32_t i = state.dt_leaves - 1; i >= 1; --i) {
    state.dt_tree[static_cast<size_t>(i)] =
        std::min(state.dt_tree[2 * static_cast<size_t>(i)], state.dt_tree[2 * static_cast<size_t>(i) + 1]);
  }
  state.dt_refreshed_step = state.step;
  state.dt_topology_version = model.topology_version();
}

template <typename T>
void UpdateStableStep(const Model<T>& model, State<T>& state, std::span<const int32_t> tets,
                      bool explicit_viscous) {
  for (const int32_t t : tets) {
    SetLeaf(state, t, ElementStableStep(model, state.x.data(), t, explicit_viscous));
  }
  state.dt_topology_version = model.topology_version();
}

template <typename T>
int32_t StableStepLimitingElement(const State<T>& state) {
  if (!std::isfinite(state.dt_tree[1])) return -1;
  size_t i = 1;
  while (i < static_cast<size_t>(state.dt_leaves)) {
    i = state.dt_tree[2 * i] == state.dt_tree[i] ? 2 * i : 2 * i + 1;
  }
  return static_cast<int32_t>(i) - state.dt_leaves;
}

namespace {

/// Largest eigenvalue of the symmetric tridiagonal matrix (diag a[0..m),
/// off-diagonal b[0..m-1)) by Sturm-count bisection: no allocation.
double TridiagonalMaxEigenvalue(const double* a, const double* b, int m) {
  double lo = a[0], hi = a[0];
  for (int i = 0; i < m; ++i) {
    const double r = (i > 0 ? std::abs(b[i - 1]) : 0.0) + (i + 1 < m ? std::abs(b[i]) : 0.0);
    lo = std::min(lo, a[i] - r);
    hi = std::max(hi, a[i] + r);
  }
  auto count_below = [&](double x) {  // eigenvalues < x
    int c = 0;
    double d = 1;
    for (int i = 0; i < m; ++i) {
      d = a[i] - x - (i > 0 ? b[i - 1] * b[i - 1] / d : 0.0);
      if (d == 0) d = -1e-300;
      c += d < 0 ? 1 : 0;
    }
    return c;
  };
  for (int it = 0; it < 200 && hi - lo > 1e-14 * std::max(std::abs(lo), std::abs(hi)); ++it) {
    const double mid = 0.5 * (lo + hi);
    (count_below(mid) >= m ? hi : lo) = mid;
  }
  return hi;
}

/// Deterministic pseudo-random start vector entry in [−1, 1).
double StartEntry(uint64_t i) {
  uint64_t h = (i + 1) * 0x9E3779B97F4A7C15ULL;
  h ^= h >> 31;
  h *= 0xBF58476D1CE4E5B9ULL;
  h ^= h >> 29;
  return static_cast<double>(h >> 11) * (2.0 / 9007199254740992.0) - 1.0;
}

/// k Lanczos steps on A = M^-1/2 · Op · M^-1/2 restricted to the free DOFs,
/// where Op is the elastic tangent K (by a one-sided finite difference of
/// the real force, so the invertible-FEM branch is included) or the damping
/// operator C (exact: the viscous force is linear in v). Returns the
/// largest Ritz value, a lower bound of λ_max(A) that converges from below.
template <typename T>
double LanczosMax(const Model<T>& model, State<T>& state, bool damping, int k, int nt, int* iterations) {
  constexpr int kMaxK = 128;
  k = std::clamp(k, 1, kMaxK);
  double alpha[kMaxK], beta[kMaxK];
  const int32_t nn = model.num_nodes();
  const T* mass = model.node_masses();
  const uint8_t* fixed = model.fixed_mask();
  const T* x = state.x.data();
  T* ef = state.element_force.data();
  auto active = [&](int32_t n) { return fixed[n] == 0 && mass[n] > T(0); };
  // Finite-difference amplitude: a small fraction of the smallest element size.
  double h_min = std::numeric_limits<double>::infinity();
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    const double g = static_cast<double>(model.grad_sq_max(t));
    if (g > 0) h_min = std::min(h_min, 1.0 / std::sqrt(g));
  }
  const double rel = sizeof(T) == 4 ? 3e-3 : 1e-6;
  const double amp = rel * h_min;
  int32_t bad = INT32_MAX;
  if (!damping) {
#pragma omp parallel num_threads(nt)
    {
      ElementForcesTeam(model, x, state.v.data(), ForceMode::kElastic, state.node_pressure.data(), ef, &bad);
#pragma omp barrier
      GatherNodeForcesTeam<T>(model, ef, nullptr, false, state.lanczos_f0.data());
    }
  }
  // q = start / |start|, prev = 0.
  double norm2 = 0;
  for (int32_t n = 0; n < nn; ++n) {
    for (int d = 0; d < 3; ++d) {
      const size_t i = static_cast<size_t>(3 * n + d);
      const double e = active(n) ? StartEntry(i) : 0.0;
      state.lanczos_q[i] = static_cast<T>(e);
      state.lanczos_prev[i] = T(0);
      norm2 += e * e;
    }
  }
  if (!(norm2 > 0)) {
    *iterations = 0;
    return 0;
  }
  const T inv_norm = static_cast<T>(1.0 / std::sqrt(norm2));
  for (int32_t i = 0; i < 3 * nn; ++i) state.lanczos_q[static_cast<size_t>(i)] *= inv_norm;
  double beta_prev = 0;
  int m = 0;
  for (int j = 0; j < k; ++j) {
    T* q = state.lanczos_q.data();
    T* prev = state.lanczos_prev.data();
    T* w = state.lanczos_w.data();
    T* xp = state.lanczos_x.data();
    // z = M^-1/2 q (scaled by eps for the finite difference), Op z, back.
    double zmax = 0;
    for (int32_t n = 0; n < nn; ++n) {
      if (!active(n)) continue;
      const double s = 1.0 / std::sqrt(static_cast<double>(mass[n]));
      for (int d = 0; d < 3; ++d) zmax = std::max(zmax, std::abs(static_cast<double>(q[3 * n + d]) * s));
    }
    const double eps = damping ? 1.0 : amp / std::max(zmax, 1e-300);
    // α = q·Aq: the same bits for any thread count (node_sums.h).
    NodeSums<1> alpha_sum(nn);
#pragma omp parallel num_threads(nt)
    {
#pragma omp for schedule(static)
      for (int32_t n = 0; n < nn; ++n) {
        const T s = active(n) ? static_cast<T>(eps / std::sqrt(static_cast<double>(mass[n]))) : T(0);
        for (int dd = 0; dd < 3; ++dd) {
          const int32_t i = 3 * n + dd;
          xp[i] = damping ? s * q[i] : x[i] + s * q[i];
        }
      }
      if (damping) {
        ElementForcesTeam<T>(model, x, xp, ForceMode::kViscousOnly, nullptr, ef, &bad);
      } else {
        ElementForcesTeam(model, xp, xp, ForceMode::kElastic, state.node_pressure.data(), ef, &bad);
      }
#pragma omp barrier
      GatherNodeForcesTeam<T>(model, ef, nullptr, false, w);
      alpha_sum.Team([&](int32_t n, std::array<double, 1>& acc) {
        const bool act = active(n);
        const double s = act ? 1.0 / (eps * std::sqrt(static_cast<double>(mass[n]))) : 0.0;
        for (int dd = 0; dd < 3; ++dd) {
          const int32_t i = 3 * n + dd;
          const double f0 = damping ? 0.0 : static_cast<double>(state.lanczos_f0[static_cast<size_t>(i)]);
          const double aq = -(static_cast<double>(w[i]) - f0) * s - beta_prev * static_cast<double>(prev[i]);
          w[i] = static_cast<T>(aq);
          acc[0] += aq * static_cast<double>(q[i]);
        }
      });
    }
    const double a = alpha_sum.Total(0);
    if (bad != INT32_MAX || !std::isfinite(a)) break;
    alpha[j] = a;
    m = j + 1;
    double b2 = 0;
    for (int32_t i = 0; i < 3 * nn; ++i) {
      w[i] -= static_cast<T>(a) * q[i];
      b2 += static_cast<double>(w[i]) * static_cast<double>(w[i]);
    }
    const double b = std::sqrt(b2);
    if (j + 1 == k || !(b > 1e-10 * std::abs(a))) break;
    beta[j] = b;
    beta_prev = b;
    const T inv_b = static_cast<T>(1.0 / b);
    for (int32_t i = 0; i < 3 * nn; ++i) w[i] *= inv_b;
    // prev ← q, q ← w (w's old storage is overwritten next iteration).
    std::swap(state.lanczos_prev, state.lanczos_q);
    std::swap(state.lanczos_q, state.lanczos_w);
  }
  *iterations = m;
  if (m == 0) return std::numeric_limits<double>::quiet_NaN();
  return TridiagonalMaxEigenvalue(alpha, beta, m);
}

}  // namespace

template <typename T>
SpectralEstimate EstimateStableStep(const Model<T>& model, State<T>& state, bool explicit_viscous,
                                    int iterations, int num_threads) {
  const int nt = num_threads > 0 ? num_threads : omp_get_max_threads();
  SpectralEstimate e;
  int it = 0;
  e.omega2_max = std::max(0.0, LanczosMax(model, state, false, iterations, nt, &it));
  e.iterations = it;
  if (explicit_viscous && model.damped()) {
    e.damping_max = std::max(0.0, LanczosMax(model, state, true, iterations, nt, &it));
    e.iterations += it;
  }
  const double c = e.damping_max, w2 = e.omega2_max;
  e.dt = (c > 0 || w2 > 0) ? 4.0 / (c + std::sqrt(c * c + 4.0 * w2))
                           : std::numeric_limits<double>::infinity();
  if (!std::isfinite(e.omega2_max) || !std::isfinite(e.damping_max)) e.dt = std::numeric_limits<double>::quiet_NaN();
  return e;
}

template <typename T>
void RefreshSpectralRatio(const Model<T>& model, State<T>& state, bool explicit_viscous, int iterations,
                          int num_threads) {
  RefreshStableStep(model, state, explicit_viscous, num_threads);
  std::copy(state.element_dt.begin(), state.element_dt.end(), state.element_dt_at_spectral.begin());
  state.dt_element_drift = 0;
  const double bound = static_cast<double>(StableStepBound(state));
  const SpectralEstimate e = EstimateStableStep(model, state, explicit_viscous, iterations, num_threads);
  double r = e.dt / bound;
  if (!std::isfinite(r)) r = 1.0;  // failed estimate, or nothing moves: the bound alone
  state.dt_ratio = std::clamp(r, 1.0, kMaxSpectralRatio);
  state.dt_bound_at_spectral = bound;
  state.dt_spectral_step = state.step;
  state.dt_spectral_topology_version = model.topology_version();
}

#define CUTSIM_FEM_INSTANTIATE(T)                                                            \
  template T ElementStableStep<T>(const Model<T>&, const T*, int32_t, bool);                 \
  template void RefreshStableStep<T>(const Model<T>&, State<T>&, bool, int);                 \
  template void UpdateStableStep<T>(const Model<T>&, State<T>&, std::span<const int32_t>, bool); \
  template int32_t StableStepLimitingElement<T>(const State<T>&);                            \
  template SpectralEstimate EstimateStableStep<T>(const Model<T>&, State<T>&, bool, int, int); \
  template void RefreshSpectralRatio<T>(const Model<T>&, State<T>&, bool, int, int);

CUTSIM_FEM_INSTANTIATE(float)
CUTSIM_FEM_INSTANTIATE(double)
#undef CUTSIM_FEM_INSTANTIATE

}  // namespace cutsim::fem
