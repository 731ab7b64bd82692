// Element-level properties: the method paper's eqs. (1)–(3) vs the standard StVK
// form, invariance, derivatives, the inversion remedy, uniaxial stress.
#include <random>

#include <gtest/gtest.h>

#include "common/fem/element.h"
#include "common/fem/forces.h"
#include "common/fem/model.h"
#include "common/fem/state.h"
#include "tests/unit/fem/test_meshes.h"

namespace cutsim::fem {
namespace {

constexpr double kLambda = 140000.0;  // method paper §4, Pa
constexpr double kMu = 11000.0;       // method paper §4, Pa

Mat34<double> RandomTet(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (;;) {
    Mat34<double> x;
    for (int i = 0; i < 12; ++i) x(i % 3, i / 3) = 0.01 * u(rng);
    if (EdgeMatrix(x).determinant() > 1e-7) return x;
  }
}

Mat3<double> RandomF(std::mt19937& rng, double amplitude) {
  std::uniform_real_distribution<double> u(-amplitude, amplitude);
  Mat3<double> F = Mat3<double>::Identity();
  for (int i = 0; i < 9; ++i) F(i / 3, i % 3) += u(rng);
  return F;
}

TEST(FemElement, MethodPaperFormEqualsStandardStvk) {
  std::mt19937 rng(1);
  double worst = 0;
  for (int trial = 0; trial < 200; ++trial) {
    const Mat34<double> u = RandomTet(rng);
    const Mat3<double> dm_inv = EdgeMatrix(u).inverse();
    const double vol = EdgeMatrix(u).determinant() / 6.0;
    // Random large deformation (including rotations/shears), not only small.
    const Mat3<double> F = RandomF(rng, 0.6);
    Mat34<double> x = F * u;
    x.colwise() += Vec3<double>(0.1, -0.2, 0.3);
    const Vec12<double> f_std = StvkElementForce<double>(x, dm_inv, vol, kLambda, kMu);
    const Vec12<double> f_seed =
        MethodPaperElementForce<double>(x, InverseBarycentric<double>(u), vol, kLambda, kMu);
    const double err = (f_std - f_seed).norm() / std::max(f_std.norm(), 1e-30);
    worst = std::max(worst, err);
    EXPECT_LT(err, 1e-9) << "trial " << trial;
  }
  RecordProperty("worst_rel_error", std::to_string(worst));
}

TEST(FemElement, BetaGradientBlockMatchesDmInverse) {
  // β's gradient block is [−1ᵀ·Dm⁻¹; Dm⁻¹]: the barycentric gradients of the tet.
  std::mt19937 rng(2);
  const Mat34<double> u = RandomTet(rng);
  const Eigen::Matrix4d beta = InverseBarycentric<double>(u);
  const Mat3<double> dm_inv = EdgeMatrix(u).inverse();
  Eigen::Matrix<double, 4, 3> G;
  G.row(0) = -dm_inv.colwise().sum();
  G.bottomRows<3>() = dm_inv;
  EXPECT_LT((beta.leftCols<3>() - G).norm(), 1e-9 * G.norm());
}

TEST(FemElement, RigidMotionGivesZeroForce) {
  std::mt19937 rng(3);
  for (int trial = 0; trial < 50; ++trial) {
    const Mat34<double> u = RandomTet(rng);
    const Mat3<double> dm_inv = EdgeMatrix(u).inverse();
    const double vol = EdgeMatrix(u).determinant() / 6.0;
    const Eigen::Quaterniond q = Eigen::Quaterniond::UnitRandom();
    Mat34<double> x = q.toRotationMatrix() * u;
    x.colwise() += Vec3<double>(1.0, 2.0, -3.0);
    const Vec12<double> f = StvkElementForce<double>(x, dm_inv, vol, kLambda, kMu);
    // Scale: a 1% stretch of the same element.
    const Vec12<double> f_ref =
        StvkElementForce<double>((1.01 * u).eval(), dm_inv, vol, kLambda, kMu);
    EXPECT_LT(f.norm(), 1e-9 * f_ref.norm());
  }
}

TEST(FemElement, ForceIsMinusEnergyGradient) {
  std::mt19937 rng(4);
  for (int trial = 0; trial < 20; ++trial) {
    const Mat34<double> u = RandomTet(rng);
    const Mat3<double> dm_inv = EdgeMatrix(u).inverse();
    const double vol = EdgeMatrix(u).determinant() / 6.0;
    const Mat34<double> x = RandomF(rng, 0.3) * u;
    const auto energy = [&](const Mat34<double>& y) {
      return vol * StvkEnergyDensity<double>(EdgeMatrix(y) * dm_inv, kLambda, kMu);
    };
    const Vec12<double> f = StvkElementForce<double>(x, dm_inv, vol, kLambda, kMu);
    const double eps = 1e-7;
    for (int i = 0; i < 12; ++i) {
      Mat34<double> xp = x, xm = x;
      xp(i % 3, i / 3) += eps;
      xm(i % 3, i / 3) -= eps;
      const double fd = -(energy(xp) - energy(xm)) / (2 * eps);
      EXPECT_NEAR(f(i), fd, 1e-6 * f.norm() + 1e-9) << "trial " << trial << " dof " << i;
    }
  }
}

TEST(FemElement, StiffnessIsMinusForceDerivativeAndSymmetric) {
  std::mt19937 rng(7);
  for (int trial = 0; trial < 20; ++trial) {
    const Mat34<double> u = RandomTet(rng);
    const Mat3<double> dm_inv = EdgeMatrix(u).inverse();
    const double vol = EdgeMatrix(u).determinant() / 6.0;
    const Mat34<double> x = RandomF(rng, 0.3) * u;
    const Eigen::Matrix<double, 12, 12> K = StvkElementStiffness<double>(x, dm_inv, vol, kLambda, kMu);
    const double eps = 1e-6;
    for (int j = 0; j < 12; ++j) {
      Mat34<double> xp = x, xm = x;
      xp(j % 3, j / 3) += eps;
      xm(j % 3, j / 3) -= eps;
      const Vec12<double> fd = -(StvkElementForce<double>(xp, dm_inv, vol, kLambda, kMu) -
                                 StvkElementForce<double>(xm, dm_inv, vol, kLambda, kMu)) / (2 * eps);
      EXPECT_LT((K.col(j) - fd).norm(), 1e-5 * K.norm()) << "trial " << trial << " dof " << j;
    }
    EXPECT_LT((K - K.transpose()).norm(), 1e-10 * K.norm()) << "a conservative force has a symmetric tangent";
    // Rigid translations are in its null space.
    for (int a = 0; a < 3; ++a) {
      Vec12<double> t = Vec12<double>::Zero();
      for (int n = 0; n < 4; ++n) t(3 * n + a) = 1.0;
      EXPECT_LT((K * t).norm(), 1e-10 * K.norm());
    }
  }
}

TEST(FemElement, DampingIsDissipativeAndZeroForRigidVelocity) {
  std::mt19937 rng(5);
  const Mat3<double> F = RandomF(rng, 0.3);
  // Rigid rotation rate: Ḟ = W F with W skew → Ė = 0.
  Mat3<double> W;
  W << 0, -1, 2, 1, 0, -3, -2, 3, 0;
  EXPECT_LT(DampingFirstPiola<double>(F, W * F, 10.0, 80.0).norm(), 1e-10);
  for (int i = 0; i < 20; ++i) {
    const Mat3<double> Fd = RandomF(rng, 1.0) - Mat3<double>::Identity();
    // Dissipation P_visc : Ḟ = S_visc : Ė ≥ 0.
    EXPECT_GE((DampingFirstPiola<double>(F, Fd, 10.0, 80.0).array() * Fd.array()).sum(), -1e-12);
  }
}

TEST(FemElement, InvertibleEqualsStvkWhenNotClamped) {
  std::mt19937 rng(6);
  for (int trial = 0; trial < 50; ++trial) {
    const Mat3<double> F = RandomF(rng, 0.25);
    Eigen::JacobiSVD<Mat3<double>> svd(F);
    if (svd.singularValues().minCoeff() < 0.35 || F.determinant() < 0) continue;
    const Mat3<double> P = StvkFirstPiola<double>(F, kLambda, kMu);
    const Mat3<double> Pi = InvertibleStvkFirstPiola<double>(F, kLambda, kMu, 0.3);
    EXPECT_LT((P - Pi).norm(), 1e-9 * P.norm() + 1e-9);
  }
}

TEST(FemElement, InvertedElementGetsRestoringForce) {
  // Node 3 pushed through the opposite face: plain StVK pushes it further
  // (or not back); the remedy's force on node 3 points back (+z).
  const mesh::TetMesh m = testing::MakeUnitTet(0.01);
  Mat34<double> u;
  for (int c = 0; c < 4; ++c) u.col(c) = m.nodes.row(c).transpose();
  const Mat3<double> dm_inv = EdgeMatrix(u).inverse();
  const double vol = EdgeMatrix(u).determinant() / 6.0;
  Mat34<double> x = u;
  x(2, 3) = -0.005;  // inverted: z of apex below base
  const Mat3<double> F = EdgeMatrix(x) * dm_inv;
  ASSERT_LT(F.determinant(), 0);
  const Vec12<double> f =
      ElementForceFromPiola<double>(InvertibleStvkFirstPiola<double>(F, kLambda, kMu, 0.3), dm_inv, vol);
  EXPECT_GT(f(11), 0.0);
}

TEST(FemElement, StressMeasures) {
  // Uniaxial Cauchy stress diag(s, 0, 0): principal (s,0,0), von Mises |s|.
  Mat3<double> s = Mat3<double>::Zero();
  s(0, 0) = 5.0;
  const Vec3<double> p = PrincipalStresses<double>(s);
  EXPECT_NEAR(p(0), 5.0, 1e-12);
  EXPECT_NEAR(p(2), 0.0, 1e-12);
  EXPECT_NEAR(VonMises<double>(s), 5.0, 1e-12);
  // Pure shear τ: von Mises √3·τ, principal ±τ.
  Mat3<double> sh = Mat3<double>::Zero();
  sh(0, 1) = sh(1, 0) = 2.0;
  EXPECT_NEAR(VonMises<double>(sh), std::sqrt(3.0) * 2.0, 1e-12);
  EXPECT_NEAR(PrincipalStresses<double>(sh)(0), 2.0, 1e-12);
}

// ---- mesh-level: patch test and uniaxial stress ---------------------------

TEST(FemPatch, UniformDeformationGivesUniformStressAndZeroInteriorForce) {
  const mesh::TetMesh mesh = testing::MakeBoxMesh(3, 3, 3, 0.03, 0.03, 0.03);
  const Material mat{.lambda = kLambda, .mu = kMu};
  Model<double> model(mesh, std::span(&mat, 1));
  State<double> state(model);
  std::mt19937 rng(7);
  const Mat3<double> F = RandomF(rng, 0.2);
  for (int n = 0; n < model.num_nodes(); ++n) {
    const Vec3<double> x = F * model.rest_position(n) + Vec3<double>(0.5, 0, 0);
    for (int d = 0; d < 3; ++d) state.x[3 * n + d] = x(d);
  }
  std::vector<double> f(state.x.size());
  ASSERT_EQ(ComputeInternalForces(model, state, ForceMode::kElastic, f.data()), -1);
  const Mat3<double> sigma = CauchyStress<double>(F, StvkFirstPiola<double>(F, kLambda, kMu));
  double fmax = 0;
  for (int n = 0; n < model.num_nodes(); ++n) {
    fmax = std::max(fmax, Vec3<double>(f[3 * n], f[3 * n + 1], f[3 * n + 2]).norm());
  }
  for (int t = 0; t < model.num_tets(); ++t) {
    EXPECT_LT((ElementCauchyStress(model, state.x.data(), t) - sigma).norm(), 1e-9 * sigma.norm());
  }
  for (int n = 0; n < model.num_nodes(); ++n) {
    const Vec3<double> u = model.rest_position(n);
    const bool interior = (u.array() > 1e-9).all() && (u.array() < 0.03 - 1e-9).all();
    if (!interior) continue;
    EXPECT_LT(Vec3<double>(f[3 * n], f[3 * n + 1], f[3 * n + 2]).norm(), 1e-9 * fmax) << n;
  }
}

TEST(FemPatch, UniaxialStressMatchesExactStvk) {
  // Uniaxial stress, lateral faces traction-free: F = diag(a, b, b) with
  // S₂₂ = λ(E₁₁ + 2E₂₂) + 2μE₂₂ = 0 ⇒ E₂₂ = −νE₁₁, ν = λ/(2(λ+μ)). Then
  // S₁₁ = E·E₁₁ with E = μ(3λ+2μ)/(λ+μ), so P₁₁ = a·S₁₁ = E·a(a²−1)/2 (exact
  // for StVK with Green strain; the lateral stretch b = √(1 − ν(a²−1))).
  // Check: the nodal forces on the x = L face sum to P₁₁·A₀ and lateral faces
  // carry zero net force.
  const double L = 0.04, H = 0.02;
  const mesh::TetMesh mesh = testing::MakeBoxMesh(4, 2, 2, L, H, H);
  const Material mat{.lambda = kLambda, .mu = kMu};
  Model<double> model(mesh, std::span(&mat, 1));
  State<double> state(model);
  const double E = kMu * (3 * kLambda + 2 * kMu) / (kLambda + kMu);
  const double nu = kLambda / (2 * (kLambda + kMu));
  for (const double a : {0.8, 1.1, 1.5}) {
    const double b = std::sqrt(1 - nu * (a * a - 1));
    for (int n = 0; n < model.num_nodes(); ++n) {
      const Vec3<double> u = model.rest_position(n);
      state.x[3 * n] = a * u(0);
      state.x[3 * n + 1] = b * u(1);
      state.x[3 * n + 2] = b * u(2);
    }
    std::vector<double> f(state.x.size());
    ComputeInternalForces(model, state, ForceMode::kElastic, f.data());
    Vec3<double> end_force = Vec3<double>::Zero(), side_force = Vec3<double>::Zero();
    for (int n = 0; n < model.num_nodes(); ++n) {
      const Vec3<double> u = model.rest_position(n);
      const Vec3<double> fn(f[3 * n], f[3 * n + 1], f[3 * n + 2]);
      if (u(0) > L - 1e-9) end_force += fn;
      if (u(1) > H - 1e-9 && u(0) > 1e-9 && u(0) < L - 1e-9) side_force += fn;
    }
    // The internal force is the reaction: the load needed is −f.
    const double expected = E * a * (a * a - 1) / 2 * H * H;
    EXPECT_NEAR(-end_force(0), expected, 1e-9 * std::abs(expected)) << "a=" << a;
    EXPECT_NEAR(side_force(1), 0.0, 1e-9 * std::abs(expected)) << "a=" << a;
  }
}

TEST(FemMesh, ForcesAreMinusEnergyGradientOnMesh) {
  const mesh::TetMesh mesh = testing::MakeBoxMesh(2, 2, 1, 0.02, 0.02, 0.01);
  const Material mat{.lambda = kLambda, .mu = kMu};
  Model<double> model(mesh, std::span(&mat, 1));
  State<double> state(model);
  std::mt19937 rng(8);
  std::uniform_real_distribution<double> u(-5e-4, 5e-4);
  for (auto& xi : state.x) xi += u(rng);
  std::vector<double> f(state.x.size());
  ASSERT_EQ(ComputeInternalForces(model, state, ForceMode::kElastic, f.data()), -1);
  const double eps = 1e-8;
  double fnorm = 0;
  for (double fi : f) fnorm = std::max(fnorm, std::abs(fi));
  for (size_t i = 0; i < 3 * static_cast<size_t>(model.num_nodes()); ++i) {
    const double x0 = state.x[i];
    state.x[i] = x0 + eps;
    const double ep = StrainEnergy(model, state.x.data());
    state.x[i] = x0 - eps;
    const double em = StrainEnergy(model, state.x.data());
    state.x[i] = x0;
    EXPECT_NEAR(f[i], -(ep - em) / (2 * eps), 1e-6 * fnorm) << "dof " << i;
  }
}

TEST(FemMesh, KernelEqualsReferenceElementForce) {
  // The blocked SIMD kernel against the pure reference kernel, per element,
  // on a non-degenerate random state: plain StVK to round-off.
  const mesh::TetMesh mesh = testing::MakeBoxMesh(3, 2, 2, 0.03, 0.02, 0.02);
  const Material mat{.lambda = kLambda, .mu = kMu};
  Model<double> model(mesh, std::span(&mat, 1));
  State<double> state(model);
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-1e-3, 1e-3);
  for (auto& xi : state.x) xi += u(rng);
  std::vector<double> f(state.x.size());
  ComputeInternalForces(model, state, ForceMode::kElastic, f.data());
  for (int t = 0; t < model.num_tets(); ++t) {
    Mat34<double> x;
    for (int c = 0; c < 4; ++c) {
      const int n = model.tet_node(t, c);
      x.col(c) = Vec3<double>(state.x[3 * n], state.x[3 * n + 1], state.x[3 * n + 2]);
    }
    ASSERT_GT(DeformationGradient(model, state.x.data(), t).determinant(), 0.3);
    const Vec12<double> ref = StvkElementForce<double>(x, model.DmInv(t), model.rest_volume(t), kLambda, kMu);
    const Eigen::Map<const Vec12<double>> got(state.element_force.data() + 12 * t);
    EXPECT_LT((got - ref).norm(), 1e-12 * ref.norm() + 1e-15) << t;
  }
}

}  // namespace
}  // namespace cutsim::fem
