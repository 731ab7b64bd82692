#include "common/cutting/criterion.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Eigenvalues>

namespace cutsim::cutting {

Eigen::Vector3d PrincipalStresses(const Eigen::Matrix3d& stress) {
  const Eigen::Matrix3d sym = 0.5 * (stress + stress.transpose());
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(sym, Eigen::EigenvaluesOnly);
  return solver.eigenvalues();  // ascending
}

CuttingStressParts CuttingStressDetail(const Eigen::Matrix3d& cauchy, double kappa, double zeta) {
  CuttingStressParts parts;
  if (!cauchy.allFinite() || !(kappa > 0.0) || !(zeta > 0.0)) return parts;
  // Eq. (8): the cutting traction uses σ/κ, so the principal values scale too.
  const Eigen::Vector3d s = PrincipalStresses(cauchy) / kappa;
  parts.sigma_max = s[2];
  // Eq. (9): with ascending eigenvalues the largest |σi − σj| is σ3 − σ1.
  parts.tau_max = 0.5 * (s[2] - s[0]);
  // Pure compression (no positive principal stress) never cuts, as in the
  // the method paper: min(σ_max, τ_max) ≤ 0 there, and we clamp it to exactly 0 so that
  // K_I = 0 cannot turn compression into a cut either. A largest principal
  // value within 1e-10·max|σi| of zero is eigen-solver round-off on a
  // compressive state with a zero principal value, not tension.
  if (!(parts.sigma_max > 1e-10 * s.cwiseAbs().maxCoeff())) return parts;
  parts.sigma_c = std::min(parts.sigma_max, parts.tau_max) / zeta;  // eq. (10)
  return parts;
}

double CuttingStress(const Eigen::Matrix3d& cauchy, double kappa, double zeta) {
  return CuttingStressDetail(cauchy, kappa, zeta).sigma_c;
}

double CuttingStressBound(const Eigen::Matrix3d& cauchy, double kappa, double zeta) {
  const Eigen::Matrix3d sym = 0.5 * (cauchy + cauchy.transpose());
  const double mean = sym.trace() / 3.0;
  const double dev = (sym - mean * Eigen::Matrix3d::Identity()).norm();
  // With deviations δi = λi − λ̄ (Σδi = 0, Σδi² = ‖dev‖²): (λ3 − λ1)² ≤ 2Σδi²
  // (the two extremes are on either side of λ̄), and δ3² ≤ (2/3)Σδi² (the
  // other two sum to −δ3). σ_c is at most the smaller of the two bounds.
  const double tau = dev * std::sqrt(0.5);
  const double sigma = mean + dev * std::sqrt(2.0 / 3.0);
  const double bound = (std::max(0.0, std::min(tau, sigma)) + 1e-12 * sym.norm()) / (kappa * zeta);
  if (!std::isfinite(bound) || !(kappa > 0.0) || !(zeta > 0.0)) return std::numeric_limits<double>::infinity();
  return bound;
}

bool ExceedsCriticalStress(double sigma_c, double critical_stress) {
  return sigma_c > 0.0 && sigma_c >= critical_stress;  // eq. (11)
}

CriterionResult EvaluateCriterion(std::span<const int32_t> candidates, const CauchyFn& cauchy,
                                  const CutParams& params) {
  CriterionResult result;
  // In candidate order, as a plain scan would go, but an eigen-solve only
  // for a candidate whose bound reaches the best σ_c so far: one below it
  // can neither be the maximum nor tie the earlier maximum. No sorting and
  // no scratch: this runs in the frame that found the contact.
  for (const int32_t t : candidates) {
    const Eigen::Matrix3d stress = cauchy(t);
    if (result.tet >= 0 && CuttingStressBound(stress, params.kappa, params.zeta) < result.sigma_c) continue;
    const double sc = CuttingStress(stress, params.kappa, params.zeta);
    if (result.tet < 0 || sc > result.sigma_c) {
      result.sigma_c = sc;
      result.tet = t;
    }
  }
  result.cut = result.tet >= 0 && ExceedsCriticalStress(result.sigma_c, params.critical_stress);
  return result;
}

void ValidateCutParams(const CutParams& p, const SourceRef& source) {
  auto fail = [&](const char* field, const char* why) {
    SourceRef s = source;
    s.field = s.field.empty() ? field : s.field + "." + field;
    ThrowInputError(s, why);
  };
  if (!(std::isfinite(p.alpha) && p.alpha > 0.0)) fail("alpha", "must be a finite number > 0");
  if (!(std::isfinite(p.kappa) && p.kappa > 0.0)) fail("kappa", "must be a finite number > 0");
  if (!(std::isfinite(p.zeta) && p.zeta > 0.0 && p.zeta <= 1.0)) fail("zeta", "must be in (0, 1]");
  if (!(std::isfinite(p.critical_stress) && p.critical_stress >= 0.0))
    fail("critical_stress", "must be a finite stress >= 0 Pa");
  if (!(std::isfinite(p.min_quality) && p.min_quality >= 0.0 && p.min_quality < 1.0))
    fail("min_quality", "must be in [0, 1)");
  if (!(std::isfinite(p.keep_quality) && p.keep_quality >= 0.0 && p.keep_quality < 1.0))
    fail("keep_quality", "must be in [0, 1)");
  if (p.t0_timeout_frames < 0) fail("t0_timeout_frames", "must be >= 0");
  if (!(std::isfinite(p.band_fraction) && p.band_fraction > 0.0 && p.band_fraction <= 2.0))
    fail("band_fraction", "must be in (0, 2]");
  if (p.max_move_halvings < 0 || p.max_move_halvings > 60) fail("max_move_halvings", "must be in [0, 60]");
  if (p.max_splits_per_step < 1) fail("max_splits_per_step", "must be >= 1");
  if (p.min_fragment_tets < 0) fail("min_fragment_tets", "must be >= 0");
}

}  // namespace cutsim::cutting
