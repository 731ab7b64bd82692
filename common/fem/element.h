#pragma once
/// @file
/// Linear-tetrahedron St. Venant–Kirchhoff element kernels as pure functions
/// on fixed-size Eigen types (ipc-toolkit style). These are the reference
/// implementations: the production force loop (forces.cc) evaluates the same
/// formulas on blocks of elements for SIMD, and the tests hold both to
/// round-off agreement.
///
/// Conventions (docs/DESIGN.md, physics): rest positions u, world positions x,
/// Dm = [u₁−u₀ u₂−u₀ u₃−u₀], Ds = [x₁−x₀ x₂−x₀ x₃−x₀], F = Ds·Dm⁻¹.
/// Node indices here are 0-based (the method paper counts 1..4).

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <Eigen/SVD>

namespace cutsim::fem {

template <typename T>
using Mat3 = Eigen::Matrix<T, 3, 3>;
template <typename T>
using Vec3 = Eigen::Matrix<T, 3, 1>;
template <typename T>
using Vec12 = Eigen::Matrix<T, 12, 1>;
/// The four node positions of one tet as columns.  // 3×4
template <typename T>
using Mat34 = Eigen::Matrix<T, 3, 4>;

/// Ds = [x₁−x₀ x₂−x₀ x₃−x₀] from the node positions (columns of `x`).  // 3×3
template <typename T>
Mat3<T> EdgeMatrix(const Mat34<T>& x) {
  Mat3<T> d;
  d.col(0) = x.col(1) - x.col(0);
  d.col(1) = x.col(2) - x.col(0);
  d.col(2) = x.col(3) - x.col(0);
  return d;
}

/// Green strain E = ½(FᵀF − I): the method paper's eq. (1) halved (docs/DESIGN.md).
template <typename T>
Mat3<T> GreenStrain(const Mat3<T>& F) {
  return T(0.5) * (F.transpose() * F - Mat3<T>::Identity());
}

/// StVK second Piola–Kirchhoff stress S = λ tr(E) I + 2μE, Pa.
template <typename T>
Mat3<T> StvkSecondPiola(const Mat3<T>& E, T lambda, T mu) {
  return lambda * E.trace() * Mat3<T>::Identity() + T(2) * mu * E;
}

/// StVK first Piola–Kirchhoff stress P = F S, Pa.
template <typename T>
Mat3<T> StvkFirstPiola(const Mat3<T>& F, T lambda, T mu) {
  return F * StvkSecondPiola(GreenStrain(F), lambda, mu);
}

/// StVK strain-energy density Ψ/vol = λ/2 tr(E)² + μ tr(E²), J/m³.
template <typename T>
T StvkEnergyDensity(const Mat3<T>& F, T lambda, T mu) {
  const Mat3<T> E = GreenStrain(F);
  const T tr = E.trace();
  return T(0.5) * lambda * tr * tr + mu * E.squaredNorm();
}

/// O'Brien–Hodgins strain-rate damping in the standard (halved) form:
/// Ė = ½(FᵀḞ + ḞᵀF), S_visc = φ tr(Ė) I + 2ψĖ, returns F·S_visc, Pa.
/// `psi` (ψ) and `phi` (φ) in Pa·s.
template <typename T>
Mat3<T> DampingFirstPiola(const Mat3<T>& F, const Mat3<T>& F_dot, T psi, T phi) {
  const Mat3<T> FtFd = F.transpose() * F_dot;
  const Mat3<T> E_dot = T(0.5) * (FtFd + FtFd.transpose());
  return F * (phi * E_dot.trace() * Mat3<T>::Identity() + T(2) * psi * E_dot);
}

/// Nodal forces of one element from its first Piola–Kirchhoff stress:
/// H = −vol·P·Dm⁻ᵀ gives nodes 1..3 (columns of H); node 0 gets minus their
/// sum, so the element force is free of net force by construction.  // 12
template <typename T>
Vec12<T> ElementForceFromPiola(const Mat3<T>& P, const Mat3<T>& dm_inv, T rest_volume) {
  const Mat3<T> H = -rest_volume * P * dm_inv.transpose();
  Vec12<T> f;
  f.template segment<3>(3) = H.col(0);
  f.template segment<3>(6) = H.col(1);
  f.template segment<3>(9) = H.col(2);
  f.template segment<3>(0) = -(H.col(0) + H.col(1) + H.col(2));
  return f;
}

/// Plain StVK element force (no damping, no inversion handling).  // 12
template <typename T>
Vec12<T> StvkElementForce(const Mat34<T>& x, const Mat3<T>& dm_inv, T rest_volume, T lambda,
                          T mu) {
  const Mat3<T> F = EdgeMatrix(x) * dm_inv;
  return ElementForceFromPiola<T>(StvkFirstPiola<T>(F, lambda, mu), dm_inv, rest_volume);
}

/// Tangent stiffness of one StVK element, K = −∂f/∂x (f from
/// StvkElementForce), exact: for node j along axis a, dDs is e_a in column
/// j (or −e_a in every column for node 0), dF = dDs·Dm⁻¹,
/// dE = sym(Fᵀ dF), dP = dF S + F (λ tr(dE) I + 2μ dE), and the column is
/// −ElementForceFromPiola(dP) (the force is linear in P).  // 12×12
template <typename T>
Eigen::Matrix<T, 12, 12> StvkElementStiffness(const Mat34<T>& x, const Mat3<T>& dm_inv, T rest_volume,
                                              T lambda, T mu) {
  const Mat3<T> F = EdgeMatrix(x) * dm_inv;
  const Mat3<T> S = StvkSecondPiola(GreenStrain(F), lambda, mu);
  Eigen::Matrix<T, 12, 12> K;
  for (int j = 0; j < 4; ++j) {
    for (int a = 0; a < 3; ++a) {
      Mat3<T> dF;  // e_a · (row j−1 of Dm⁻¹), or −e_a · (sum of its rows) for node 0
      const Eigen::Matrix<T, 1, 3> g = j == 0 ? Eigen::Matrix<T, 1, 3>(-dm_inv.colwise().sum())
                                              : Eigen::Matrix<T, 1, 3>(dm_inv.row(j - 1));
      dF.setZero();
      dF.row(a) = g;
      const Mat3<T> FtdF = F.transpose() * dF;
      const Mat3<T> dE = T(0.5) * (FtdF + FtdF.transpose());
      const Mat3<T> dS = lambda * dE.trace() * Mat3<T>::Identity() + T(2) * mu * dE;
      K.col(3 * j + a) = -ElementForceFromPiola<T>(dF * S + F * dS, dm_inv, rest_volume);
    }
  }
  return K;
}

/// The method paper's β: the 4×4 inverse of the barycentric matrix [u₀ u₁ u₂ u₃; 1 1 1 1],
/// so barycentric coordinates are b = β·[u; 1].  // 4×4
template <typename T>
Eigen::Matrix<T, 4, 4> InverseBarycentric(const Mat34<T>& u) {
  Eigen::Matrix<T, 4, 4> A;
  A.template topRows<3>() = u;
  A.row(3).setOnes();
  return A.inverse();
}

/// Reference implementation of the method paper's eqs. (1)–(3) taken literally:
/// ε_kl = ∂x/∂u_k·∂x/∂u_l − δ_kl (eq. 1, no ½), σ = λ tr(ε) I + 2με (eq. 2),
/// f_i = −vol/2 Σ_j p_j Σ_k Σ_l β_jl β_ik σ_kl (eq. 3). With ∂x/∂u_l =
/// Σ_j p_j β_jl this equals StvkElementForce (σ = 2S, and eq. 3's ½ undoes it).
/// `p` world positions (columns), `beta` from InverseBarycentric.  // 12
template <typename T>
Vec12<T> MethodPaperElementForce(const Mat34<T>& p, const Eigen::Matrix<T, 4, 4>& beta, T vol, T lambda,
                          T mu) {
  // dx/du_l for l = 0..2: column l of p·β(:, 0..2).
  const Mat3<T> dxdu = p * beta.template leftCols<3>();
  Mat3<T> eps;
  for (int k = 0; k < 3; ++k) {
    for (int l = 0; l < 3; ++l) {
      eps(k, l) = dxdu.col(k).dot(dxdu.col(l)) - (k == l ? T(1) : T(0));  // eq. (1)
    }
  }
  Mat3<T> sigma;  // eq. (2)
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      sigma(i, j) = (i == j ? lambda * eps.trace() : T(0)) + T(2) * mu * eps(i, j);
    }
  }
  Vec12<T> f;
  for (int i = 0; i < 4; ++i) {  // eq. (3)
    Vec3<T> fi = Vec3<T>::Zero();
    for (int j = 0; j < 4; ++j) {
      T w = 0;
      for (int k = 0; k < 3; ++k) {
        for (int l = 0; l < 3; ++l) w += beta(j, l) * beta(i, k) * sigma(k, l);
      }
      fi += p.col(j) * w;
    }
    f.template segment<3>(3 * i) = -vol / T(2) * fi;
  }
  return f;
}

/// Invertible StVK (Irving, Teran, Fedkiw 2004, "Invertible finite elements
/// for robust simulation of large deformation"): F = U F̂ Vᵀ with proper
/// rotations U, V (a reflection moves into the smallest singular value, which
/// becomes negative for an inverted element), singular values clamped to
/// ≥ `min_singular_value`, P̂ = diagonal StVK stress of the clamped F̂, and
/// P = U P̂ Vᵀ. A clamped direction keeps the restoring stress of a
/// compression to `min_singular_value`, which pushes an inverted element back
/// through zero volume. For F with all σᵢ ≥ clamp this equals StvkFirstPiola
/// (to round-off), so the remedy is continuous where it switches on.
template <typename T>
Mat3<T> InvertibleStvkFirstPiola(const Mat3<T>& F, T lambda, T mu, T min_singular_value) {
  // SVD in double: cheap for 3×3 and this path runs only for degenerate elements.
  const Mat3<double> Fd = F.template cast<double>();
  Eigen::JacobiSVD<Mat3<double>> svd(Fd, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Mat3<double> U = svd.matrixU();
  Mat3<double> V = svd.matrixV();
  Vec3<double> s = svd.singularValues();  // descending, ≥ 0
  if (U.determinant() < 0) {
    U.col(2) *= -1.0;
    s(2) *= -1.0;
  }
  if (V.determinant() < 0) {
    V.col(2) *= -1.0;
    s(2) *= -1.0;
  }
  const double c = static_cast<double>(min_singular_value);
  for (int i = 0; i < 3; ++i) s(i) = std::max(s(i), c);
  const Vec3<double> e = 0.5 * (s.array().square() - 1.0).matrix();  // diagonal Green strain
  const double tr = e.sum();
  Vec3<double> p_hat;
  for (int i = 0; i < 3; ++i) {
    p_hat(i) = s(i) * (static_cast<double>(lambda) * tr + 2.0 * static_cast<double>(mu) * e(i));
  }
  return (U * p_hat.asDiagonal() * V.transpose()).template cast<T>();
}

/// Cauchy stress σ = (1/J) P Fᵀ, J = det F, Pa. Undefined for J ≤ 0: the
/// caller gets zero there (a collapsed element carries no meaningful stress).
template <typename T>
Mat3<T> CauchyStress(const Mat3<T>& F, const Mat3<T>& P) {
  const T J = F.determinant();
  if (!(J > T(0))) return Mat3<T>::Zero();
  const Mat3<T> s = P * F.transpose() / J;
  return T(0.5) * (s + s.transpose());  // symmetric up to round-off; make it exact
}

/// Principal stresses of a symmetric stress, descending (σ₁ ≥ σ₂ ≥ σ₃), Pa.
template <typename T>
Vec3<T> PrincipalStresses(const Mat3<T>& sigma) {
  Eigen::SelfAdjointEigenSolver<Mat3<double>> es;
  es.computeDirect(sigma.template cast<double>(), Eigen::EigenvaluesOnly);
  const Vec3<double> ev = es.eigenvalues();  // ascending
  return Vec3<T>(static_cast<T>(ev(2)), static_cast<T>(ev(1)), static_cast<T>(ev(0)));
}

/// Von Mises equivalent stress √(3/2 s:s), s the deviator of σ, Pa.
template <typename T>
T VonMises(const Mat3<T>& sigma) {
  const Mat3<T> dev = sigma - sigma.trace() / T(3) * Mat3<T>::Identity();
  return std::sqrt(T(1.5) * dev.squaredNorm());
}

/// Upper bound of the largest eigenvalue of a symmetric 3×3 matrix by
/// Gershgorin's theorem (exact for diagonal matrices, e.g. F = I).
template <typename T>
T GershgorinMax(const Mat3<T>& A) {
  T m = -std::numeric_limits<T>::infinity();
  for (int i = 0; i < 3; ++i) {
    T r = A(i, i);
    for (int j = 0; j < 3; ++j) {
      if (j != i) r += std::abs(A(i, j));
    }
    m = std::max(m, r);
  }
  return m;
}

}  // namespace cutsim::fem
