#include "common/fem/stable_dt.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "common/fem/forces.h"

namespace cutsim::fem {

template <typename T>
T ElementStableStep(const Model<T>& model, const T* x, int32_t t, bool explicit_viscous) {
  const T vol = model.rest_volume(t);
  const T m = model.element_mass(t) / T(4);
  if (!(vol > T(0)) || !(m > T(0))) return std::numeric_limits<T>::infinity();
  const Mat3<T> F = DeformationGradient(model, x, t);
  const Mat3<T> C = F.transpose() * F;
  const T s2 = GershgorinMax<T>(C);  // ≥ σ_max(F)²
  const T lam = model.lambdas()[t], mu = model.mus()[t];
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
#pragma omp parallel num_threads(num_threads > 0 ? num_threads : omp_get_max_threads())
  {
#pragma omp for schedule(static)
    for (int32_t t = 0; t < nt; ++t) {
      const T dt = ElementStableStep(model, x, t, explicit_viscous);
      elem[t] = dt;
      leaves[t] = dt;
    }
  }
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

#define CUTSIM_FEM_INSTANTIATE(T)                                                            \
  template T ElementStableStep<T>(const Model<T>&, const T*, int32_t, bool);                 \
  template void RefreshStableStep<T>(const Model<T>&, State<T>&, bool, int);                 \
  template void UpdateStableStep<T>(const Model<T>&, State<T>&, std::span<const int32_t>, bool); \
  template int32_t StableStepLimitingElement<T>(const State<T>&);

CUTSIM_FEM_INSTANTIATE(float)
CUTSIM_FEM_INSTANTIATE(double)

}  // namespace cutsim::fem
