#pragma once
/// @file
/// Whole-mesh force, energy and stress evaluation. The force loop is two
/// passes, both parallel without atomics: (1) per element, in SIMD blocks of
/// Model::kBlock, the 12 nodal forces into the #T×12 element-force buffer;
/// (2) per node, a gather of its (tet, corner) slots through the model's
/// node→element CSR. The `*Team` functions contain orphaned `omp for` loops:
/// call them from inside a parallel region (the integrator fuses a whole
/// step into one), or from outside for a serial run.

#include <cstdint>
#include <span>
#include <vector>

#include "common/fem/element.h"
#include "common/fem/model.h"
#include "common/fem/state.h"

namespace cutsim::fem {

enum class ForceMode {
  kElastic,        ///< StVK only (damping skipped entirely).
  kElasticDamped,  ///< StVK + strain-rate damping, P = F(S + S_visc).
  kViscousOnly,    ///< F·S_visc(v) only: the linear damping operator (implicit CG).
};

/// Pass 1 for all tets: writes `element_force` (#T_pad×12). Elements with
/// det F < model.inversion_det_threshold() use the invertible StVK
/// (element.h). If any element force is non-finite, the smallest such tet
/// index is min-reduced into `*bad_tet` (initialise it to INT32_MAX).
/// With the nodal-pressure element (and an elastic mode) two passes come
/// first: the nodes' volume ratios J_a and pressures p_a = U'(J_a) into
/// `node_pressure` (#N scratch; unused, may be null, otherwise), then the
/// element pass adds p̄_e·cof(F) to each P (nodal_pressure.h).
template <typename T>
void ElementForcesTeam(const Model<T>& model, const T* x, const T* v, ForceMode mode,
                       T* node_pressure, T* element_force, int32_t* bad_tet);

/// Pass 2 for all nodes: out[n] = Σ element forces of n (+ external f_ext if
/// non-null + prescribed + m·g when `add_loads`).  // out #N×3
template <typename T>
void GatherNodeForcesTeam(const Model<T>& model, const T* element_force, const T* f_ext,
                          bool add_loads, T* out);

/// Internal (elastic + damping unless mode says otherwise) nodal forces of
/// the state into `out` (#N×3), using `state.element_force` and
/// `state.node_pressure` as scratch.
/// Returns the first non-finite tet or −1.
template <typename T>
int32_t ComputeInternalForces(const Model<T>& model, State<T>& state, ForceMode mode, T* out,
                              int num_threads = 0);

/// F of tet t at positions x.  // 3×3
template <typename T>
Mat3<T> DeformationGradient(const Model<T>& model, const T* x, int32_t t);

/// Strain energy Σ vol·(λ/2 tr(E)² + μ tr(E²)), J (accumulated in double);
/// with the nodal-pressure element Σ_e V_e·μ|dev E_e|² + Σ_a V_a·U(J_a).
template <typename T>
double StrainEnergy(const Model<T>& model, const T* x);
/// Kinetic energy ½ Σ m|v|², J.
template <typename T>
double KineticEnergy(const Model<T>& model, const T* v);
/// Gravity potential −Σ m g·x, J (zero at the origin).
template <typename T>
double GravityPotential(const Model<T>& model, const T* x);

/// Cauchy stress σ = (1/J) P Fᵀ of tet t (elastic part, with the inversion
/// remedy where it is active; zero if J ≤ 0), Pa. With the nodal-pressure
/// element: the element's deviatoric part plus p̄·I, p̄ the mean of its
/// nodes' pressures U'(J_a) (nodal_pressure.h), so the stress the cut
/// criterion reads is the one the element carries.
template <typename T>
Mat3<T> ElementCauchyStress(const Model<T>& model, const T* x, int32_t t);

/// The nodal-pressure element's pressure U'(J_a) at every node, Pa (#N;
/// zero at a node without patch volume, all zero for the linear element).
/// One pass over the tets (their current volumes into `tet_volume`, #T
/// scratch) and one over the nodes, so a whole-mesh stress field costs
/// O(#T) where ElementCauchyStress per tet costs O(#T × patch size).
template <typename T>
void ComputeNodePressures(const Model<T>& model, const T* x, std::vector<double>& tet_volume,
                          std::vector<double>& node_pressure, int num_threads = 0);

/// ElementCauchyStress with the nodes' pressures of ComputeNodePressures
/// (#N) at the same x: the whole-mesh form.
template <typename T>
Mat3<T> ElementCauchyStress(const Model<T>& model, const T* x, int32_t t, std::span<const double> node_pressure);

/// Per-tet stress fields for cutting and output: largest principal Cauchy
/// stress σ₁, smallest σ₃, and von Mises, Pa. Spans of length num_tets()
/// (or empty to skip).
template <typename T>
void ComputeElementStresses(const Model<T>& model, const T* x, std::span<T> sigma_max,
                            std::span<T> sigma_min, std::span<T> von_mises, int num_threads = 0);

}  // namespace cutsim::fem
