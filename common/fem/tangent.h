#pragma once
/// @file
/// Per-element tangents of the implicit step in 3×3 node blocks, closed
/// form. With shape-function gradients g_a (F = Σ_a x_a g_aᵀ, so the force on
/// node a is f_a = −vol·P·g_a) and h_a = F·g_a:
///
///   StVK stiffness  K_ab = −∂f_a/∂x_b
///     = vol·[(g_aᵀ S g_b) I + λ h_a h_bᵀ + μ (g_a·g_b) F Fᵀ + μ h_b h_aᵀ],
///   strain-rate damping  C_ab = −∂f_a/∂v_b (at fixed F)
///     = vol·[φ h_a h_bᵀ + ψ (g_a·g_b) F Fᵀ + ψ h_b h_aᵀ].
///
/// The material part (λ, μ terms) is the quadratic form λ tr(dE)² + 2μ dE:dE
/// and so positive semidefinite; only the geometric term (g_aᵀ S g_b) I can
/// make K indefinite, where S has a negative eigenvalue (compression).
/// Replacing S by its positive part S⁺ there gives a positive semidefinite
/// K⁺ that equals K wherever S ⪰ 0. The same blocks equal
/// StvkElementStiffness (element.h) to round-off (tests/unit/fem).

#include <Eigen/Core>
#include <Eigen/Eigenvalues>

#include "common/fem/element.h"

namespace cutsim::fem {

/// 3×3 blocks of one element's 12×12 matrix: blocks[4·a + b] = M_ab.
using ElementBlocks = Eigen::Matrix3d[16];

/// Shape-function gradients as columns: g_j = (row j−1 of Dm⁻¹)ᵀ for j ≥ 1,
/// g_0 = −(g_1 + g_2 + g_3).  // 3×4
inline Mat34<double> ShapeGradients(const Mat3<double>& dm_inv) {
  Mat34<double> g;
  g.rightCols<3>() = dm_inv.transpose();
  g.col(0) = -(g.col(1) + g.col(2) + g.col(3));
  return g;
}

/// The positive semidefinite part of a symmetric 3×3 matrix (negative
/// eigenvalues set to 0). Returns `s` itself, without an eigensolve, when
/// every principal minor is non-negative (then s ⪰ 0).
inline Mat3<double> PositivePart(const Mat3<double>& s) {
  const double m01 = s(0, 0) * s(1, 1) - s(0, 1) * s(0, 1);
  const double m02 = s(0, 0) * s(2, 2) - s(0, 2) * s(0, 2);
  const double m12 = s(1, 1) * s(2, 2) - s(1, 2) * s(1, 2);
  if (s(0, 0) >= 0 && s(1, 1) >= 0 && s(2, 2) >= 0 && m01 >= 0 && m02 >= 0 && m12 >= 0 &&
      s.determinant() >= 0) {
    return s;
  }
  Eigen::SelfAdjointEigenSolver<Mat3<double>> es;
  es.computeDirect(s);
  const Vec3<double> ev = es.eigenvalues().cwiseMax(0.0);
  return es.eigenvectors() * ev.asDiagonal() * es.eigenvectors().transpose();
}

/// Writes vol·[geo_ab I + a1 h_a h_bᵀ + a2 (g_a·g_b) F Fᵀ + a2 h_b h_aᵀ] into
/// `out`, with geo_ab = g_aᵀ S g_b (S may be zero). K: (S, λ, μ); C: (0, φ, ψ).
inline void ElementTangentBlocks(const Mat3<double>& F, const Mat3<double>& S,
                                 const Mat34<double>& g, double vol, double a1, double a2,
                                 ElementBlocks& out) {
  const Mat34<double> h = F * g;
  const Mat3<double> fft = F * F.transpose();
  const Mat34<double> sg = S * g;
  for (int a = 0; a < 4; ++a) {
    for (int b = a; b < 4; ++b) {
      const double geo = g.col(a).dot(sg.col(b));
      const double gg = g.col(a).dot(g.col(b));
      Mat3<double> m = (vol * a1) * h.col(a) * h.col(b).transpose() +
                       (vol * a2) * h.col(b) * h.col(a).transpose() + (vol * a2 * gg) * fft;
      m.diagonal().array() += vol * geo;
      out[4 * a + b] = m;
      if (b != a) out[4 * b + a] = m.transpose();
    }
  }
}

/// Plain StVK energy vol·Ψ(F) (J) and nodal forces f_a = −vol·P·g_a (N,
/// `force` columns) of one element, consistent with StvkElementForce.
inline double StvkEnergyAndForce(const Mat3<double>& F, const Mat34<double>& g, double vol,
                                 double lambda, double mu, Mat3<double>* S, Mat34<double>* force) {
  const Mat3<double> E = GreenStrain(F);
  *S = StvkSecondPiola(E, lambda, mu);
  *force = (-vol) * (F * (*S)) * g;
  const double tr = E.trace();
  return vol * (0.5 * lambda * tr * tr + mu * E.squaredNorm());
}

}  // namespace cutsim::fem
