#pragma once
/// @file
/// Physical cut criterion (method paper §3.1, eqs. 6–11): the Cauchy stress of the
/// contact elements, scaled by 1/κ, is reduced to its principal values;
/// σ_max is the largest, τ_max half the largest pairwise difference
/// (eq. 9), σ_c = min(σ_max, τ_max)/ζ (eq. 10), and the tissue cuts iff
/// σ_c ≥ K_I (eq. 11). Pure compression (σ_max ≤ 0) never cuts.

#include <cstdint>
#include <functional>
#include <span>

#include <Eigen/Core>

#include "common/cutting/cut_params.h"

namespace cutsim::cutting {

/// Principal values of the symmetric part of `stress`, ascending, Pa.
Eigen::Vector3d PrincipalStresses(const Eigen::Matrix3d& stress);

/// Parts of eq. (10) for one stress tensor (already scaled by 1/κ).
struct CuttingStressParts {
  double sigma_max = 0.0;  ///< Largest principal stress, Pa.
  double tau_max = 0.0;    ///< Largest principal half-difference (eq. 9), Pa.
  double sigma_c = 0.0;    ///< Cutting stress (eq. 10), Pa; 0 under pure compression.
};

/// Eqs. (8)–(10) for a Cauchy stress `cauchy` (Pa), sharpness κ > 0, damage
/// ζ > 0. Non-finite input gives σ_c = 0 (never cuts).
CuttingStressParts CuttingStressDetail(const Eigen::Matrix3d& cauchy, double kappa, double zeta);

/// σ_c of eq. (10), Pa.
double CuttingStress(const Eigen::Matrix3d& cauchy, double kappa, double zeta);

/// An upper bound on CuttingStress(cauchy, κ, ζ) without an eigen-solve:
/// σ_c ≤ min(σ_max, τ_max)/ζ with (λ3 − λ1)/2 ≤ ‖dev σ‖_F/√2 and
/// λ3 ≤ tr σ/3 + √(2/3)·‖dev σ‖_F (σ symmetrized), plus 1e-12·‖σ‖_F/(κζ),
/// far above the eigen-solver's round-off. +∞ for non-finite input or
/// κ, ζ ≤ 0 (then nothing is bounded).
double CuttingStressBound(const Eigen::Matrix3d& cauchy, double kappa, double zeta);

/// Eq. (11): σ_c > 0 and σ_c ≥ K_I.
bool ExceedsCriticalStress(double sigma_c, double critical_stress);

/// Cauchy stress of tet `t`, Pa, supplied by the FEM side.
using CauchyFn = std::function<Eigen::Matrix3d(int32_t t)>;

struct CriterionResult {
  bool cut = false;       ///< Eq. (11) holds for the most stressed candidate.
  double sigma_c = 0.0;   ///< Largest σ_c over the candidates, Pa.
  int32_t tet = -1;       ///< Candidate that gave it (−1 if none).
};

/// Evaluates the criterion over the contact elements only (the tets
/// incident to the contact facet / v_c; see CutMesh::ContactElements): the
/// maximum σ_c decides. Ties keep the first candidate (deterministic).
/// A candidate whose CuttingStressBound is below the best σ_c so far is
/// skipped without an eigen-solve: the same result as solving every
/// candidate. No allocation.
CriterionResult EvaluateCriterion(std::span<const int32_t> candidates, const CauchyFn& cauchy,
                                  const CutParams& params);

}  // namespace cutsim::cutting
