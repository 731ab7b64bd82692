#pragma once
/// @file
/// The volumetric part of the average-nodal-pressure linear tetrahedron
/// (Bonet & Burton 1998; NiftySim's T4-ANP, Joldes, Wittek & Miller 2009),
/// the remedy for volumetric locking of linear tets in nearly incompressible
/// tissue. An element's strain energy is split into a deviatoric part, kept
/// per element, and a volumetric part that lives on the nodes:
///
///   W = Σ_e V_e·μ|dev E_e|² + Σ_a V_a·U(J_a),
///   J_a = v_a / V_a,  v_a = Σ_{e∋a} v_e/4,  V_a = Σ_{e∋a} V_e/4,
///
/// v_e = V_e·det F_e the element's current volume, V_e its rest volume, and
/// U(J) = κ/4·(J² − 1 − 2 ln J) (convex for J > 0, infinite as J → 0,
/// U''(1) = κ the bulk modulus). μ|dev E|² is StVK with λ = −2μ/3 (element.h,
/// tangent.h), so with κ = λ + 2μ/3 the split energy equals StVK to second
/// order in the strain. The nodal volume ratio J_a averages the volume change
/// over the node's patch, so a patch, not each element, must keep its
/// volume: the constraint count drops to about one per node and the mesh no
/// longer locks.
///
/// Forces (−∂W/∂x of the volumetric part) stay element-local once the nodal
/// pressures p_a = U'(J_a) are known: f_c = −Σ_{e∋c} p̄_e·∂v_e/∂x_c with
/// p̄_e = ¼ Σ_{a∈e} p_a (the averaged pressure of the element). The tangent is
///
///   K_vol = Σ_a (U''(J_a)/V_a)·∇v_a ∇v_aᵀ + Σ_e p̄_e·∂²v_e/∂x²,
///   ∇v_a = ¼ Σ_{e∋a} ∇v_e,
///
/// whose first term couples every pair of nodes of a patch (two element
/// rings apart): NodalPressureHessianProduct applies it without assembling.
///
/// These are the double-precision reference implementations, one pass over
/// the model each; the tests hold them to finite differences.

#include <cmath>
#include <cstdint>
#include <span>
#include <vector>

#include <Eigen/Core>

#include "common/fem/element.h"
#include "common/fem/model.h"

namespace cutsim::fem {

/// U(J) = κ/4·(J² − 1 − 2 ln J), J/m³ of rest volume; +∞ for J ≤ 0.
inline double VolumetricEnergyDensity(double J, double kappa) {
  if (!(J > 0)) return std::numeric_limits<double>::infinity();
  return 0.25 * kappa * (J * J - 1.0 - 2.0 * std::log(J));
}
/// p = U'(J) = κ/2·(J − 1/J), Pa (positive in tension).
inline double VolumetricPressure(double J, double kappa) { return 0.5 * kappa * (J - 1.0 / J); }
/// U''(J) = κ/2·(1 + 1/J²), Pa.
inline double VolumetricModulus(double J, double kappa) { return 0.5 * kappa * (1.0 + 1.0 / (J * J)); }

/// cof(F) = det(F)·F⁻ᵀ, as the columns f₂×f₃, f₃×f₁, f₁×f₂ of F's columns
/// (polynomial: defined for singular F too).  // 3×3
template <typename T>
inline Mat3<T> Cofactor(const Mat3<T>& F) {
  Mat3<T> c;
  c.col(0) = F.col(1).cross(F.col(2));
  c.col(1) = F.col(2).cross(F.col(0));
  c.col(2) = F.col(0).cross(F.col(1));
  return c;
}

/// ∂v_e/∂x_a = V_e·cof(F)·g_a for the four nodes (g: shape-function
/// gradients, tangent.h ShapeGradients), m².  // 3×4
inline Mat34<double> VolumeGradient(const Mat3<double>& F, const Mat34<double>& g, double rest_volume) {
  return rest_volume * Cofactor(F) * g;
}

/// ∂²v_e/∂x_a∂x_b = −V_e·[F·(g_a × g_b)]×, m (skew; zero for a = b).  // 3×3
inline Mat3<double> VolumeHessianBlock(const Mat3<double>& F, const Vec3<double>& ga, const Vec3<double>& gb,
                                       double rest_volume) {
  const Vec3<double> w = -rest_volume * (F * ga.cross(gb));
  Mat3<double> m;
  m << 0, -w(2), w(1), w(2), 0, -w(0), -w(1), w(0), 0;
  return m;
}

/// ¼ Σ_{a∈t} values[a]: the element average of a nodal field (p̄_e from the
/// nodal pressures).
inline double ElementMean(const Model<double>& model, int32_t t, const std::vector<double>& values) {
  double s = 0;
  for (int c = 0; c < 4; ++c) s += values[static_cast<size_t>(model.tet_node(t, c))];
  return 0.25 * s;
}

/// Per-node bulk modulus κ_a = Σ_{e∋a} κ_e V_e / Σ_{e∋a} V_e (Pa) and rest
/// patch volume V_a = Σ_{e∋a} V_e/4 (m³) of the model's nodes, from the
/// per-tet bulk moduli `kappa` (#T). Nodes without elements get 0.
void NodalRestVolumes(const Model<double>& model, std::span<const double> kappa,
                      std::vector<double>& node_kappa, std::vector<double>& node_volume);

/// The volumetric energy Σ_a V_a·U(J_a) (J) at positions x (#N×3); adds its
/// forces −∂W/∂x into `force` (#N×3, N) when not null, and writes the nodal
/// volume ratios J_a into `node_j` (#N) when not null. +∞ if some J_a ≤ 0.
double NodalPressureEnergyAndForce(const Model<double>& model, std::span<const double> kappa, const double* x,
                                   double* force, double* node_j = nullptr);

/// out += K_vol·p (#N×3): the volumetric tangent at x applied to p.
void NodalPressureHessianProduct(const Model<double>& model, std::span<const double> kappa, const double* x,
                                 const double* p, double* out);

}  // namespace cutsim::fem
