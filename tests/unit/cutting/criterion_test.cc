// Physical criterion (seed eqs. 6–11): properties first, then values.
#include <limits>
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
