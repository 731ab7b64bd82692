// Physical criterion (method paper eqs. 6–11): properties first, then values.
#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include <gtest/gtest.h>

#include "common/core/error.h"
#include "common/cutting/criterion.h"

namespace cutsim::cutting {
namespace {

using Eigen::Matrix3d;

Matrix3d Rotated(const Matrix3d& s) {
  const Matrix3d R =
      (Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitX()) * Eigen::AngleAxisd(-1.1, Eigen::Vector3d::UnitY()))
          .toRotationMatrix();
  return R * s * R.transpose();
}

TEST(CuttingStress, UniaxialTensionMatchesEquations9And10) {
  // σ = diag(s, 0, 0): σ_max = s, τ_max = s/2 → σ_c = s/(2κζ).
  const double s = 3.0e4, kappa = 2.0, zeta = 0.5;
  const CuttingStressParts p = CuttingStressDetail(Rotated(Eigen::Vector3d(s, 0, 0).asDiagonal()), kappa, zeta);
  EXPECT_NEAR(p.sigma_max, s / kappa, 1e-9 * s);
  EXPECT_NEAR(p.tau_max, 0.5 * s / kappa, 1e-9 * s);
  EXPECT_NEAR(p.sigma_c, 0.5 * s / (kappa * zeta), 1e-9 * s);
  EXPECT_DOUBLE_EQ(CuttingStress(Rotated(Eigen::Vector3d(s, 0, 0).asDiagonal()), kappa, zeta), p.sigma_c);
}

TEST(CuttingStress, RotationInvariant) {
  const Matrix3d s = Eigen::Vector3d(5e3, -2e3, 1e3).asDiagonal();
  EXPECT_NEAR(CuttingStress(s, 1.3, 0.7), CuttingStress(Rotated(s), 1.3, 0.7), 1e-9);
}

TEST(CuttingStress, MinOfNormalAndShearDecides) {
  // Tension with strong lateral compression: τ_max = (s + c)/2 > σ_max = s.
  const double s = 1e3, c = 5e3;
  EXPECT_NEAR(CuttingStress(Eigen::Vector3d(s, 0, -c).asDiagonal(), 1.0, 1.0), s, 1e-9);
  // Hydrostatic tension has no shear: τ_max = 0, never cuts.
  EXPECT_EQ(CuttingStress(Matrix3d::Identity() * 1e6, 1.0, 1.0), 0.0);
}

TEST(CuttingStress, PureCompressionNeverCuts) {
  for (const Eigen::Vector3d& d : {Eigen::Vector3d(-1e3, -2e3, -5e4), Eigen::Vector3d(0, -1e5, -1e5),
                                  Eigen::Vector3d(0, 0, -1e9)}) {
    const double sc = CuttingStress(Rotated(d.asDiagonal()), 1.0, 0.1);
    EXPECT_EQ(sc, 0.0);
    EXPECT_FALSE(ExceedsCriticalStress(sc, 0.0)) << "K_I = 0 must not make compression cut";
  }
}

TEST(CuttingStress, NonFiniteNeverCuts) {
  Matrix3d s = Matrix3d::Identity();
  s(0, 1) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(CuttingStress(s, 1.0, 1.0), 0.0);
}

TEST(Criterion, CutsAboveCriticalStressOnlyAndTakesTheMaxOverCandidates) {
  CutParams params;
  params.kappa = 1.0;
  params.zeta = 1.0;
  params.critical_stress = 1.0e4;
  // Tet t carries uniaxial tension t·1e4 Pa → σ_c = t·5e3 Pa.
  const CauchyFn cauchy = [](int32_t t) -> Matrix3d {
    return Eigen::Vector3d(1.0e4 * t, 0, 0).asDiagonal();
  };
  const std::vector<int32_t> low{0, 1};  // σ_c ≤ 5e3 < K_I
  CriterionResult r = EvaluateCriterion(low, cauchy, params);
  EXPECT_FALSE(r.cut);
  EXPECT_EQ(r.tet, 1);
  EXPECT_DOUBLE_EQ(r.sigma_c, 5.0e3);
  const std::vector<int32_t> high{1, 3, 2};  // max σ_c = 1.5e4 ≥ K_I
  r = EvaluateCriterion(high, cauchy, params);
  EXPECT_TRUE(r.cut);
  EXPECT_EQ(r.tet, 3);
  const std::vector<int32_t> exact{2};  // σ_c = K_I exactly: eq. (11) is ≥
  EXPECT_TRUE(EvaluateCriterion(exact, cauchy, params).cut);
  EXPECT_FALSE(EvaluateCriterion({}, cauchy, params).cut);
  // ζ < 1 (damage) lowers the stress needed.
  params.zeta = 0.5;
  EXPECT_TRUE(EvaluateCriterion(low, cauchy, params).cut);
  // A blunter tool (κ > 1) raises it.
  params.zeta = 1.0;
  params.kappa = 2.0;
  EXPECT_FALSE(EvaluateCriterion(exact, cauchy, params).cut);
}

// The bound that lets EvaluateCriterion skip eigen-solves must hold for
// every stress, near-hydrostatic ones (where the eigen-solver's round-off
// is all of τ_max) included.
TEST(CuttingStress, BoundHoldsForRandomAndNearHydrostaticStresses) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  auto random = [&](double scale) {
    Matrix3d a;
    for (int i = 0; i < 9; ++i) a(i / 3, i % 3) = scale * u(rng);
    return a;
  };
  int checked = 0;
  for (int k = 0; k < 20000; ++k) {
    const double scale = std::pow(10.0, 6.0 * u(rng));
    Matrix3d s = random(scale);
    switch (k % 5) {
      case 1: s = scale * u(rng) * Matrix3d::Identity() + 1e-13 * random(scale); break;  // near-hydrostatic
      case 2: s = Eigen::Vector3d(scale * u(rng), 0.0, -scale).asDiagonal(); s = Rotated(s); break;
      case 3: s = 0.5 * (s + s.transpose()); break;
      // Tension against a larger equal-biaxial compression: σ_max < τ_max
      // and the σ_max bound is exact (equal lower pair).
      case 4: s = Eigen::Vector3d(0.5 * scale * std::abs(u(rng)), -scale, -scale).asDiagonal(); break;
      default: break;  // not symmetric: the criterion uses the symmetric part
    }
    for (const double kappa : {0.5, 1.0, 3.0}) {
      const double zeta = 0.25 + 0.75 * (0.5 + 0.5 * u(rng));
      ASSERT_GE(CuttingStressBound(s, kappa, zeta), CuttingStress(s, kappa, zeta)) << s << "\nk " << k;
      ++checked;
    }
  }
  EXPECT_EQ(checked, 60000);
  Matrix3d bad = Matrix3d::Identity();
  bad(0, 1) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(CuttingStressBound(bad, 1.0, 1.0), std::numeric_limits<double>::infinity());
}

// Skipping solves by the bound must give exactly the first maximum of a
// plain scan, ties (repeated and rotated stresses) and compression included.
TEST(Criterion, BoundedSearchEqualsAFullScan) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  CutParams params;
  params.kappa = 1.5;
  params.zeta = 0.8;
  params.critical_stress = 0.3;
  for (int trial = 0; trial < 2000; ++trial) {
    const int n = 1 + trial % 30;
    std::vector<Matrix3d> stress(static_cast<size_t>(n));
    for (auto& s : stress) {
      for (int i = 0; i < 9; ++i) s(i / 3, i % 3) = u(rng);
      if (u(rng) > 0.5) s = -s.transpose() * s;  // compression only: σ_c = 0
    }
    // Ties: exact repeats and rotated copies (equal up to round-off).
    for (int r = 0; r < n / 3; ++r) {
      const auto a = static_cast<size_t>(std::uniform_int_distribution<int>(0, n - 1)(rng));
      const auto b = static_cast<size_t>(std::uniform_int_distribution<int>(0, n - 1)(rng));
      stress[b] = r % 2 == 0 ? stress[a] : Rotated(stress[a]);
    }
    std::vector<int32_t> candidates(static_cast<size_t>(n));
    for (int i = 0; i < n; ++i) candidates[static_cast<size_t>(i)] = 100 + 7 * ((i * 13) % n);  // not sorted
    const CauchyFn cauchy = [&](int32_t t) { return stress[static_cast<size_t>(((t - 100) / 7))]; };
    CriterionResult scan;
    for (const int32_t t : candidates) {
      const double sc = CuttingStress(cauchy(t), params.kappa, params.zeta);
      if (scan.tet < 0 || sc > scan.sigma_c) {
        scan.sigma_c = sc;
        scan.tet = t;
      }
    }
    scan.cut = ExceedsCriticalStress(scan.sigma_c, params.critical_stress);
    const CriterionResult r = EvaluateCriterion(candidates, cauchy, params);
    ASSERT_EQ(r.tet, scan.tet) << "trial " << trial;
    ASSERT_EQ(r.sigma_c, scan.sigma_c) << "trial " << trial;
    ASSERT_EQ(r.cut, scan.cut) << "trial " << trial;
  }
}

TEST(CutParams, ValidationNamesTheField) {
  CutParams p;
  EXPECT_NO_THROW(ValidateCutParams(p, SourceRef{.file = "scene.txt", .field = "cutting"}));
  p.zeta = 0.0;
  try {
    ValidateCutParams(p, SourceRef{.file = "scene.txt", .field = "cutting"});
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source().field, "cutting.zeta");
    EXPECT_NE(std::string(e.what()).find("scene.txt"), std::string::npos);
  }
  p = CutParams{};
  p.min_quality = 1.5;
  EXPECT_THROW(ValidateCutParams(p, {}), InputError);
  p = CutParams{};
  p.alpha = std::numeric_limits<double>::infinity();
  EXPECT_THROW(ValidateCutParams(p, {}), InputError);
}

}  // namespace
}  // namespace cutsim::cutting
