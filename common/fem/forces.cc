#include "common/fem/forces.h"

#include <omp.h>

#include <algorithm>
#include <climits>
#include <cmath>
#include <vector>

#include "common/fem/nodal_pressure.h"
#include "common/fem/threads.h"

namespace cutsim::fem {

namespace {

constexpr int kW = Model<double>::kBlock;

/// One SIMD block of kW elements starting at t0 (StVK per docs/DESIGN.md):
/// F = Ds·Dm⁻¹, E = ½(FᵀF − I), S = λ tr(E) I + 2μE [+ φ tr(Ė) I + 2ψĖ],
/// P = F S, H = −vol·P·Dm⁻ᵀ, node 0 gets −ΣH. Straight-line code over the
/// lanes of a `omp simd` loop so GCC vectorises across elements; the
/// irregular parts (node gathers, the inversion fallback) stay outside it.
template <typename T, ForceMode kMode, bool kPressure>
void ElementBlock(const Model<T>& model, const T* __restrict x, const T* __restrict v,
                  const T* __restrict node_pressure, int32_t t0, T* __restrict ef, int32_t* bad_tet) {
  constexpr bool kElastic = kMode != ForceMode::kViscousOnly;
  static_assert(kElastic || !kPressure);
  constexpr bool kDamped = kMode != ForceMode::kElastic;
  const int32_t* tets = model.tets() + 4 * t0;
  alignas(64) T ds[9][kW];  // Ds, row-major components
  alignas(64) T dv[9][kW];  // Ḋs = velocity edge matrix (damping only)
  for (int l = 0; l < kW; ++l) {
    const int32_t* tn = tets + 4 * l;
    const T* x0 = x + 3 * tn[0];
    for (int c = 0; c < 3; ++c) {
      const T* xc = x + 3 * tn[c + 1];
      for (int r = 0; r < 3; ++r) ds[3 * r + c][l] = xc[r] - x0[r];
    }
    if constexpr (kDamped) {
      const T* v0 = v + 3 * tn[0];
      for (int c = 0; c < 3; ++c) {
        const T* vc = v + 3 * tn[c + 1];
        for (int r = 0; r < 3; ++r) dv[3 * r + c][l] = vc[r] - v0[r];
      }
    }
  }
  const T* __restrict b[9];
  for (int k = 0; k < 9; ++k) b[k] = model.dm_inv(k) + t0;
  const T* __restrict vol = model.rest_volumes() + t0;
  const T* __restrict lam = model.element_lambdas() + t0;
  const T* __restrict mu = model.mus() + t0;
  const T* __restrict psi = model.psis() + t0;
  const T* __restrict phi = model.phis() + t0;
  alignas(64) T out[12][kW];
  alignas(64) T det[kW];
  alignas(64) T p_bar[kW];  // nodal-pressure element: the mean pressure of the tet's nodes, Pa
  if constexpr (kPressure) {
    for (int l = 0; l < kW; ++l) {
      const int32_t* tn = tets + 4 * l;
      p_bar[l] = T(0.25) * (node_pressure[tn[0]] + node_pressure[tn[1]] + node_pressure[tn[2]] +
                            node_pressure[tn[3]]);
    }
  }

#pragma omp simd
  for (int l = 0; l < kW; ++l) {
    const T B[9] = {b[0][l], b[1][l], b[2][l], b[3][l], b[4][l],
                    b[5][l], b[6][l], b[7][l], b[8][l]};
    T F[9];
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {
        F[3 * r + c] = ds[3 * r][l] * B[c] + ds[3 * r + 1][l] * B[3 + c] + ds[3 * r + 2][l] * B[6 + c];
      }
    }
    // S (symmetric; s00 s11 s22 s01 s02 s12).
    T s00 = 0, s11 = 0, s22 = 0, s01 = 0, s02 = 0, s12 = 0;
    if constexpr (kElastic) {
      // C = FᵀF, E = ½(C − I).
      const T c00 = F[0] * F[0] + F[3] * F[3] + F[6] * F[6];
      const T c11 = F[1] * F[1] + F[4] * F[4] + F[7] * F[7];
      const T c22 = F[2] * F[2] + F[5] * F[5] + F[8] * F[8];
      const T c01 = F[0] * F[1] + F[3] * F[4] + F[6] * F[7];
      const T c02 = F[0] * F[2] + F[3] * F[5] + F[6] * F[8];
      const T c12 = F[1] * F[2] + F[4] * F[5] + F[7] * F[8];
      const T e00 = T(0.5) * (c00 - T(1)), e11 = T(0.5) * (c11 - T(1)), e22 = T(0.5) * (c22 - T(1));
      const T ltr = lam[l] * (e00 + e11 + e22);
      const T m2 = T(2) * mu[l];
      s00 = ltr + m2 * e00;
      s11 = ltr + m2 * e11;
      s22 = ltr + m2 * e22;
      s01 = m2 * T(0.5) * c01;
      s02 = m2 * T(0.5) * c02;
      s12 = m2 * T(0.5) * c12;
      det[l] = F[0] * (F[4] * F[8] - F[5] * F[7]) - F[1] * (F[3] * F[8] - F[5] * F[6]) +
               F[2] * (F[3] * F[7] - F[4] * F[6]);
    } else {
      det[l] = T(1);
    }
    if constexpr (kDamped) {
      T Fd[9];
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) {
          Fd[3 * r + c] = dv[3 * r][l] * B[c] + dv[3 * r + 1][l] * B[3 + c] + dv[3 * r + 2][l] * B[6 + c];
        }
      }
      // Ė = ½(FᵀḞ + ḞᵀF): Ė_ij = ½ Σ_r (F_ri Ḟ_rj + Ḟ_ri F_rj).
      auto edot = [&](int i, int j) {
        return T(0.5) * (F[i] * Fd[j] + F[3 + i] * Fd[3 + j] + F[6 + i] * Fd[6 + j] +
                         Fd[i] * F[j] + Fd[3 + i] * F[3 + j] + Fd[6 + i] * F[6 + j]);
      };
      const T d00 = edot(0, 0), d11 = edot(1, 1), d22 = edot(2, 2);
      const T d01 = edot(0, 1), d02 = edot(0, 2), d12 = edot(1, 2);
      const T ptr = phi[l] * (d00 + d11 + d22);
      const T p2 = T(2) * psi[l];
      s00 += ptr + p2 * d00;
      s11 += ptr + p2 * d11;
      s22 += ptr + p2 * d22;
      s01 += p2 * d01;
      s02 += p2 * d02;
      s12 += p2 * d12;
    }
    // P = F S.
    T P[9];
    for (int r = 0; r < 3; ++r) {
      P[3 * r + 0] = F[3 * r] * s00 + F[3 * r + 1] * s01 + F[3 * r + 2] * s02;
      P[3 * r + 1] = F[3 * r] * s01 + F[3 * r + 1] * s11 + F[3 * r + 2] * s12;
      P[3 * r + 2] = F[3 * r] * s02 + F[3 * r + 1] * s12 + F[3 * r + 2] * s22;
    }
    if constexpr (kPressure) {
      // P += p̄·cof(F), cof(F) = ∂det F/∂F with columns f₁×f₂, f₂×f₀, f₀×f₁:
      // the element's share of the nodal volumetric force (nodal_pressure.h).
      const T p = p_bar[l];
      P[0] += p * (F[4] * F[8] - F[7] * F[5]);
      P[3] += p * (F[7] * F[2] - F[1] * F[8]);
      P[6] += p * (F[1] * F[5] - F[4] * F[2]);
      P[1] += p * (F[5] * F[6] - F[8] * F[3]);
      P[4] += p * (F[8] * F[0] - F[2] * F[6]);
      P[7] += p * (F[2] * F[3] - F[5] * F[0]);
      P[2] += p * (F[3] * F[7] - F[6] * F[4]);
      P[5] += p * (F[6] * F[1] - F[0] * F[7]);
      P[8] += p * (F[0] * F[4] - F[3] * F[1]);
    }
    // H = −vol·P·Dm⁻ᵀ: H_rc = −vol Σ_k P_rk B_ck.
    const T nv = -vol[l];
    for (int r = 0; r < 3; ++r) {
      T hsum = 0;
      for (int c = 0; c < 3; ++c) {
        const T h = nv * (P[3 * r] * B[3 * c] + P[3 * r + 1] * B[3 * c + 1] + P[3 * r + 2] * B[3 * c + 2]);
        out[3 * (c + 1) + r][l] = h;
        hsum += h;
      }
      out[r][l] = -hsum;
    }
  }

  T check = 0;
  for (int l = 0; l < kW; ++l) {
    T* e = ef + 12 * (t0 + l);
    for (int k = 0; k < 12; ++k) {
      e[k] = out[k][l];
      check += out[k][l];
    }
  }
  if constexpr (kElastic) {
    // Degenerate or inverted elements: the Irving et al. remedy (element.h).
    // Rare, so a scalar path outside the SIMD loop; inert padding has vol 0.
    const T thr = model.inversion_det_threshold();
    for (int l = 0; l < kW; ++l) {
      if (!(det[l] >= thr) && vol[l] > T(0)) [[unlikely]] {
        const int32_t t = t0 + l;
        Mat3<T> Ds, Bm = model.DmInv(t);
        for (int k = 0; k < 9; ++k) Ds(k / 3, k % 3) = ds[k][l];
        const Mat3<T> Fm = Ds * Bm;
        // A non-finite F must stay visible to the guard (the SVD could turn
        // it into finite garbage).
        if (!Fm.allFinite()) continue;
        Mat3<T> P = InvertibleStvkFirstPiola<T>(Fm, lam[l], mu[l], model.min_singular_value());
        if constexpr (kPressure) P += p_bar[l] * Cofactor<T>(Fm);
        if constexpr (kDamped) {
          Mat3<T> Dv;
          for (int k = 0; k < 9; ++k) Dv(k / 3, k % 3) = dv[k][l];
          P += DampingFirstPiola<T>(Fm, Dv * Bm, psi[l], phi[l]);
        }
        const Vec12<T> fe = ElementForceFromPiola<T>(P, Bm, vol[l]);
        T* e = ef + 12 * t;
        for (int k = 0; k < 12; ++k) {
          e[k] = fe(k);
          check += fe(k);
        }
      }
    }
  }
  if (!std::isfinite(check)) [[unlikely]] {
    for (int l = 0; l < kW; ++l) {
      const T* e = ef + 12 * (t0 + l);
      for (int k = 0; k < 12; ++k) {
        if (!std::isfinite(e[k])) *bad_tet = std::min(*bad_tet, t0 + l);
      }
    }
  }
}

template <typename T, ForceMode kMode, bool kPressure = false>
void ElementLoop(const Model<T>& model, const T* x, const T* v, const T* node_pressure, T* ef,
                 int32_t* bad_tet) {
  const int32_t num_blocks = model.padded_tets() / kW;
  int32_t local_bad = INT32_MAX;
#pragma omp for schedule(static)
  for (int32_t blk = 0; blk < num_blocks; ++blk) {
    ElementBlock<T, kMode, kPressure>(model, x, v, node_pressure, blk * kW, ef, &local_bad);
  }
  if (local_bad != INT32_MAX) [[unlikely]] {
#pragma omp critical(cutsim_fem_bad_tet)
    *bad_tet = std::min(*bad_tet, local_bad);
  }
}

/// The nodal-pressure element's first two passes: each tet's quarter of its
/// current volume v_e/4 = V_e·det F/4 into ef[t] (`ef` as #T_pad scratch:
/// the force pass overwrites it), then per node, through the
/// node→element CSR, J_a = Σ v_e/4 / V_a and p_a = U'(J_a) into
/// `node_pressure` (#N). J_a is held at or above kMinNodalVolumeRatio, where
/// U' already pushes back with about 18κ: a patch turned inside out keeps a
/// finite restoring pressure instead of a pole or a sign flip.
template <typename T>
void NodalPressuresTeam(const Model<T>& model, const T* x, T* ef, T* node_pressure) {
  constexpr T kMinNodalVolumeRatio = T(0.027);
  const int32_t num_blocks = model.padded_tets() / kW;
#pragma omp for schedule(static)
  for (int32_t blk = 0; blk < num_blocks; ++blk) {
    // v_e/4 = V_e·det F/4 = det(Ds)/24 (V_e = det(Dm)/6 > 0 for every
    // element with a volume; degenerate ones and the padding carry none).
    const int32_t t0 = blk * kW;
    const int32_t* tets = model.tets() + 4 * t0;
    const T* __restrict vol = model.rest_volumes() + t0;
    alignas(64) T quarter[kW];
    for (int l = 0; l < kW; ++l) {
      const int32_t* tn = tets + 4 * l;
      const T* x0 = x + 3 * tn[0];
      const T* x1 = x + 3 * tn[1];
      const T* x2 = x + 3 * tn[2];
      const T* x3 = x + 3 * tn[3];
      const T a0 = x1[0] - x0[0], a1 = x2[0] - x0[0], a2 = x3[0] - x0[0];
      const T a3 = x1[1] - x0[1], a4 = x2[1] - x0[1], a5 = x3[1] - x0[1];
      const T a6 = x1[2] - x0[2], a7 = x2[2] - x0[2], a8 = x3[2] - x0[2];
      const T d = a0 * (a4 * a8 - a5 * a7) - a1 * (a3 * a8 - a5 * a6) + a2 * (a3 * a7 - a4 * a6);
      quarter[l] = vol[l] > T(0) ? d * T(1.0 / 24.0) : T(0);
    }
    for (int l = 0; l < kW; ++l) ef[t0 + l] = quarter[l];
  }
  const int32_t* range = model.incidence_ranges();
  const int32_t* slots = model.incidence_slots();
  const int32_t nn = model.num_nodes();
#pragma omp for schedule(static)
  for (int32_t n = 0; n < nn; ++n) {
    const T rest = model.node_rest_volume(n);
    T now = 0;
    for (int32_t k = range[2 * n]; k < range[2 * n + 1]; ++k) now += ef[slots[k] / 12];
    const T j = rest > T(0) ? std::max(now / rest, kMinNodalVolumeRatio) : T(1);
    node_pressure[n] = T(0.5) * model.node_kappa(n) * (j - T(1) / j);
  }
}

}  // namespace

template <typename T>
void ElementForcesTeam(const Model<T>& model, const T* x, const T* v, ForceMode mode,
                       T* node_pressure, T* element_force, int32_t* bad_tet) {
  static_assert(Model<T>::kBlock == kW);
  const bool pressure = model.element() == ElementKind::kNodalPressure && mode != ForceMode::kViscousOnly;
  if (pressure) NodalPressuresTeam(model, x, element_force, node_pressure);
  switch (mode) {
    case ForceMode::kElastic:
      if (pressure) {
        ElementLoop<T, ForceMode::kElastic, true>(model, x, v, node_pressure, element_force, bad_tet);
      } else {
        ElementLoop<T, ForceMode::kElastic>(model, x, v, nullptr, element_force, bad_tet);
      }
      break;
    case ForceMode::kElasticDamped:
      if (pressure) {
        ElementLoop<T, ForceMode::kElasticDamped, true>(model, x, v, node_pressure, element_force, bad_tet);
      } else {
        ElementLoop<T, ForceMode::kElasticDamped>(model, x, v, nullptr, element_force, bad_tet);
      }
      break;
    case ForceMode::kViscousOnly:
      ElementLoop<T, ForceMode::kViscousOnly>(model, x, v, nullptr, element_force, bad_tet);
      break;
  }
}

template <typename T>
void GatherNodeForcesTeam(const Model<T>& model, const T* element_force, const T* f_ext,
                          bool add_loads, T* out) {
  const int32_t* range = model.incidence_ranges();
  const int32_t* slots = model.incidence_slots();
  const T* mass = model.node_masses();
  const T* pf = model.prescribed_forces();
  const Vec3<T> g = model.gravity();
  // Skip the gravity work when gravity is off.
  const bool gravity = add_loads && g.squaredNorm() > T(0);
  const int32_t n_nodes = model.num_nodes();
#pragma omp for schedule(static)
  for (int32_t n = 0; n < n_nodes; ++n) {
    T f0 = 0, f1 = 0, f2 = 0;
    for (int32_t k = range[2 * n]; k < range[2 * n + 1]; ++k) {
      const T* e = element_force + slots[k];
      f0 += e[0];
      f1 += e[1];
      f2 += e[2];
    }
    if (add_loads) {
      f0 += pf[3 * n];
      f1 += pf[3 * n + 1];
      f2 += pf[3 * n + 2];
      if (gravity) {
        f0 += mass[n] * g(0);
        f1 += mass[n] * g(1);
        f2 += mass[n] * g(2);
      }
      if (f_ext != nullptr) {
        f0 += f_ext[3 * n];
        f1 += f_ext[3 * n + 1];
        f2 += f_ext[3 * n + 2];
      }
    }
    out[3 * n] = f0;
    out[3 * n + 1] = f1;
    out[3 * n + 2] = f2;
  }
}

template <typename T>
int32_t ComputeInternalForces(const Model<T>& model, State<T>& state, ForceMode mode, T* out,
                              int num_threads) {
  int32_t bad = INT32_MAX;
  T* ef = state.element_force.data();
#pragma omp parallel num_threads(Threads(num_threads))
  {
    ElementForcesTeam(model, state.x.data(), state.v.data(), mode, state.node_pressure.data(), ef, &bad);
#pragma omp barrier
    GatherNodeForcesTeam<T>(model, ef, nullptr, false, out);
  }
  return bad == INT32_MAX ? -1 : bad;
}

template <typename T>
Mat3<T> DeformationGradient(const Model<T>& model, const T* x, int32_t t) {
  Mat34<T> xs;
  for (int c = 0; c < 4; ++c) {
    const int32_t n = model.tet_node(t, c);
    xs.col(c) = Vec3<T>(x[3 * n], x[3 * n + 1], x[3 * n + 2]);
  }
  return EdgeMatrix(xs) * model.DmInv(t);
}

template <typename T>
double StrainEnergy(const Model<T>& model, const T* x) {
  const bool nodal = model.element() == ElementKind::kNodalPressure;
  std::vector<double> node_volume(nodal ? static_cast<size_t>(model.num_nodes()) : 0, 0.0);
  double e = 0;
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    const Mat3<double> F = DeformationGradient(model, x, t).template cast<double>();
    const double vol = static_cast<double>(model.rest_volume(t));
    e += vol * StvkEnergyDensity<double>(F, static_cast<double>(model.element_lambdas()[t]),
                                         static_cast<double>(model.mus()[t]));
    if (nodal) {
      for (int c = 0; c < 4; ++c) node_volume[static_cast<size_t>(model.tet_node(t, c))] += 0.25 * vol * F.determinant();
    }
  }
  for (int32_t n = 0; n < static_cast<int32_t>(node_volume.size()); ++n) {
    const double rest = static_cast<double>(model.node_rest_volume(n));
    if (rest > 0) {
      e += rest * VolumetricEnergyDensity(node_volume[static_cast<size_t>(n)] / rest,
                                          static_cast<double>(model.node_kappa(n)));
    }
  }
  return e;
}

template <typename T>
double KineticEnergy(const Model<T>& model, const T* v) {
  double e = 0;
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    const double v2 = static_cast<double>(v[3 * n] * v[3 * n] + v[3 * n + 1] * v[3 * n + 1] +
                                          v[3 * n + 2] * v[3 * n + 2]);
    e += 0.5 * static_cast<double>(model.node_mass(n)) * v2;
  }
  return e;
}

template <typename T>
double GravityPotential(const Model<T>& model, const T* x) {
  double e = 0;
  const Vec3<double> g = model.gravity().template cast<double>();
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    const Vec3<double> p(x[3 * n], x[3 * n + 1], x[3 * n + 2]);
    e -= static_cast<double>(model.node_mass(n)) * g.dot(p);
  }
  return e;
}

namespace {

/// p̄ = ¼ Σ_{a∈t} U'(J_a) of the nodal-pressure element, each J_a from the
/// current volumes of node a's incident tets (a query for one tet).
template <typename T>
double ElementMeanNodalPressure(const Model<T>& model, const T* x, int32_t t) {
  const int32_t* slots = model.incidence_slots();
  double sum = 0;
  for (int c = 0; c < 4; ++c) {
    const int32_t a = model.tet_node(t, c);
    const double rest = static_cast<double>(model.node_rest_volume(a));
    if (!(rest > 0)) continue;
    double now = 0;
    for (int32_t k = model.incidence_begin(a); k < model.incidence_end(a); ++k) {
      const int32_t e = slots[k] / 12;
      now += 0.25 * static_cast<double>(model.rest_volume(e)) *
             static_cast<double>(DeformationGradient(model, x, e).determinant());
    }
    const double j = now / rest;
    sum += VolumetricPressure(j, static_cast<double>(model.node_kappa(a)));
  }
  return 0.25 * sum;
}

/// The element's elastic Cauchy stress (the inversion remedy where it is
/// active), without the nodal-pressure element's p̄·I.
template <typename T>
Mat3<T> ElementElasticCauchyStress(const Model<T>& model, const T* x, int32_t t) {
  const Mat3<T> F = DeformationGradient(model, x, t);
  const T lam = model.element_lambdas()[t], mu = model.mus()[t];
  const Mat3<T> P = F.determinant() >= model.inversion_det_threshold()
                        ? StvkFirstPiola<T>(F, lam, mu)
                        : InvertibleStvkFirstPiola<T>(F, lam, mu, model.min_singular_value());
  return CauchyStress<T>(F, P);
}

}  // namespace

template <typename T>
Mat3<T> ElementCauchyStress(const Model<T>& model, const T* x, int32_t t) {
  Mat3<T> sigma = ElementElasticCauchyStress(model, x, t);
  if (model.element() == ElementKind::kNodalPressure) {
    sigma.diagonal().array() += static_cast<T>(ElementMeanNodalPressure(model, x, t));
  }
  return sigma;
}

template <typename T>
void ComputeNodePressures(const Model<T>& model, const T* x, std::vector<double>& tet_volume,
                          std::vector<double>& node_pressure, int num_threads) {
  const int32_t nt = model.num_tets();
  const int32_t nn = model.num_nodes();
  node_pressure.assign(static_cast<size_t>(nn), 0.0);
  if (model.element() != ElementKind::kNodalPressure) return;
  tet_volume.resize(static_cast<size_t>(nt));
  const int32_t* slots = model.incidence_slots();
#pragma omp parallel num_threads(Threads(num_threads))
  {
    // A quarter of each tet's current volume, once per tet.
#pragma omp for schedule(static)
    for (int32_t t = 0; t < nt; ++t) {
      tet_volume[static_cast<size_t>(t)] = 0.25 * static_cast<double>(model.rest_volume(t)) *
                                           static_cast<double>(DeformationGradient(model, x, t).determinant());
    }
    // Each node gathers its patch's volume: no write is shared.
#pragma omp for schedule(static)
    for (int32_t a = 0; a < nn; ++a) {
      const double rest = static_cast<double>(model.node_rest_volume(a));
      if (!(rest > 0)) continue;
      double now = 0;
      for (int32_t k = model.incidence_begin(a); k < model.incidence_end(a); ++k) {
        now += tet_volume[static_cast<size_t>(slots[k] / 12)];
      }
      node_pressure[static_cast<size_t>(a)] = VolumetricPressure(now / rest, static_cast<double>(model.node_kappa(a)));
    }
  }
}

template <typename T>
Mat3<T> ElementCauchyStress(const Model<T>& model, const T* x, int32_t t, std::span<const double> node_pressure) {
  Mat3<T> sigma = ElementElasticCauchyStress(model, x, t);
  if (model.element() == ElementKind::kNodalPressure) {
    double sum = 0;
    for (int c = 0; c < 4; ++c) sum += node_pressure[static_cast<size_t>(model.tet_node(t, c))];
    sigma.diagonal().array() += static_cast<T>(0.25 * sum);
  }
  return sigma;
}

template <typename T>
void ComputeElementStresses(const Model<T>& model, const T* x, std::span<T> sigma_max,
                            std::span<T> sigma_min, std::span<T> von_mises, int num_threads) {
  const int32_t nt = model.num_tets();
  std::vector<double> tet_volume;
  std::vector<double> node_pressure;
  ComputeNodePressures(model, x, tet_volume, node_pressure, num_threads);
#pragma omp parallel for schedule(static) num_threads(Threads(num_threads))
  for (int32_t t = 0; t < nt; ++t) {
    const Mat3<T> s = ElementCauchyStress(model, x, t, std::span<const double>(node_pressure));
    const Vec3<T> p = PrincipalStresses<T>(s);
    if (!sigma_max.empty()) sigma_max[static_cast<size_t>(t)] = p(0);
    if (!sigma_min.empty()) sigma_min[static_cast<size_t>(t)] = p(2);
    if (!von_mises.empty()) von_mises[static_cast<size_t>(t)] = VonMises<T>(s);
  }
}

#define CUTSIM_FEM_INSTANTIATE(T)                                                              \
  template void ElementForcesTeam<T>(const Model<T>&, const T*, const T*, ForceMode, T*, T*,   \
                                     int32_t*);                                                \
  template void GatherNodeForcesTeam<T>(const Model<T>&, const T*, const T*, bool, T*);       \
  template int32_t ComputeInternalForces<T>(const Model<T>&, State<T>&, ForceMode, T*, int);   \
  template Mat3<T> DeformationGradient<T>(const Model<T>&, const T*, int32_t);                \
  template double StrainEnergy<T>(const Model<T>&, const T*);                                  \
  template double KineticEnergy<T>(const Model<T>&, const T*);                                 \
  template double GravityPotential<T>(const Model<T>&, const T*);                              \
  template Mat3<T> ElementCauchyStress<T>(const Model<T>&, const T*, int32_t);                \
  template Mat3<T> ElementCauchyStress<T>(const Model<T>&, const T*, int32_t, std::span<const double>); \
  template void ComputeNodePressures<T>(const Model<T>&, const T*, std::vector<double>&,      \
                                        std::vector<double>&, int);                          \
  template void ComputeElementStresses<T>(const Model<T>&, const T*, std::span<T>, std::span<T>, \
                                          std::span<T>, int);

CUTSIM_FEM_INSTANTIATE(float)
CUTSIM_FEM_INSTANTIATE(double)
#undef CUTSIM_FEM_INSTANTIATE

}  // namespace cutsim::fem
