// The nodal-pressure element in the implicit step: Newton converges
// quadratically on its Jacobian (assembled local part + matrix-free patch
// part), the element does not lock where the linear tet does, a block
// compressed by 20 % at ν = 0.499 keeps its volume, and after a cut-like
// node split the nodal averages equal a rebuild.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <vector>

#include "common/fem/implicit.h"
#include "common/fem/nodal_pressure.h"
#include "tests/unit/fem/implicit_fixtures.h"

namespace cutsim::fem {
namespace {

/// A cantilever 60 × 10 × 10 mm (12 × 2 × 2 cells) of Young's modulus
/// `youngs` (Pa), clamped at x = 0, under gravity. At 1 MPa its tip sags
/// ~2 mm (Euler–Bernoulli: 1.9 mm), at 30 kPa by half its thickness and more.
Model<double> Cantilever(double nu, ElementKind element, double youngs = 1e6) {
  const mesh::TetMesh mesh = testing::MakeBoxMesh(12, 2, 2, 0.06, 0.01, 0.01);
  const Material mat = Material::FromYoungPoisson(youngs, nu, 1000.0);
  ModelOptions opt;
  opt.element = element;
  opt.gravity = Eigen::Vector3d(0, 0, -9.81);
  Model<double> model(mesh, std::span(&mat, 1), opt);
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    if (model.rest_position(n)(0) < 1e-9) model.SetFixed(n, true);
  }
  return model;
}

ImplicitOptions Static() {
  ImplicitOptions o;
  o.asynchronous_factorization = false;
  o.relative_force_tolerance = 1e-10;
  o.linear_tolerance = 1e-12;
  o.max_newton_iterations = 60;
  o.max_pcg_iterations = 2000;
  return o;
}

/// Mean vertical displacement of the free end (x = 0.06) at equilibrium, m.
double StaticTip(const Model<double>& model) {
  State<double> state(model);
  ImplicitOptions o = Static();
  o.relative_force_tolerance = 1e-8;  // 1e-10 of this load is below round-off
  ImplicitIntegrator integ(o);
  const ImplicitResult r = integ.Step(model, state, 100.0);
  EXPECT_TRUE(r.ok()) << "residual " << r.residual << " tolerance " << r.tolerance;
  double sum = 0;
  int count = 0;
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    if (model.rest_position(n)(0) > 0.06 - 1e-9) {
      sum += state.x[static_cast<size_t>(3 * n + 2)] - model.rest_position(n)(2);
      ++count;
    }
  }
  return sum / count;
}

TEST(ImplicitNodalPressure, NewtonConvergesQuadratically) {
  const Model<double> model = Cantilever(0.49, ElementKind::kNodalPressure, 3e4);
  State<double> state(model);
  ImplicitOptions opt = Static();
  opt.tangent = TangentMode::kExact;
  opt.tangent_reuse_contraction = 0;
  ImplicitIntegrator integ(opt);
  const ImplicitResult r = integ.Step(model, state, 100.0);
  ASSERT_TRUE(r.ok()) << "residual " << r.residual << " after " << r.newton_iterations;
  const double scale = r.tolerance / 1e-10;
  EXPECT_TRUE(testing::HasQuadraticStep(r, scale));
}

// The linear tet locks as ν → ½: on this coarse beam its tip sags 4× less at
// 0.49 than at 0.3, where the continuum's changes by about 3 %. The
// nodal-pressure element removes the volumetric locking (its ratio is
// ~0.8 here; what is left is the linear tet's stiffness in bending on two
// elements across).
TEST(ImplicitNodalPressure, DoesNotLockWhereTheLinearTetDoes) {
  const double linear_ratio = StaticTip(Cantilever(0.49, ElementKind::kLinear)) /
                              StaticTip(Cantilever(0.3, ElementKind::kLinear));
  const double anp_ratio = StaticTip(Cantilever(0.49, ElementKind::kNodalPressure)) /
                           StaticTip(Cantilever(0.3, ElementKind::kNodalPressure));
  EXPECT_LT(linear_ratio, 0.4);
  EXPECT_GT(anp_ratio, 0.75);
  EXPECT_LT(anp_ratio, 1.05);
}

// A block pressed to 80 % of its height between two clamped faces keeps its
// volume within 1 % at ν = 0.499 (it bulges sideways instead).
TEST(ImplicitNodalPressure, CompressedBlockKeepsItsVolume) {
  const mesh::TetMesh mesh = testing::MakeBoxMesh(4, 4, 4, 0.02, 0.02, 0.02);
  const Material mat = Material::FromYoungPoisson(1e4, 0.499, 1000.0);
  ModelOptions opt;
  opt.element = ElementKind::kNodalPressure;
  const Model<double> probe(mesh, std::span(&mat, 1), opt);
  Model<double> model(mesh, std::span(&mat, 1), opt);
  State<double> state(model);
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    const double z = model.rest_position(n)(2);
    if (z < 1e-9 || z > 0.02 - 1e-9) model.SetFixed(n, true);
    if (z > 0.02 - 1e-9) state.x[static_cast<size_t>(3 * n + 2)] = 0.016;
  }
  ImplicitOptions o = Static();
  o.relative_force_tolerance = 0;
  o.force_tolerance = 1e-9;
  ImplicitIntegrator integ(o);
  // Load steps of 5 %: from rest, the first Newton step would invert elements.
  for (int k = 1; k <= 4; ++k) {
    for (int32_t n = 0; n < model.num_nodes(); ++n) {
      if (model.rest_position(n)(2) > 0.02 - 1e-9) state.x[static_cast<size_t>(3 * n + 2)] = 0.02 * (1 - 0.05 * k);
    }
    std::fill(state.v.begin(), state.v.end(), 0.0);
    const ImplicitResult r = integ.Step(model, state, 100.0);
    ASSERT_TRUE(r.ok()) << "load step " << k << ": residual " << r.residual;
  }
  double volume = 0;
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    Mat34<double> xe;
    for (int c = 0; c < 4; ++c) xe.col(c) = Eigen::Map<const Eigen::Vector3d>(state.x.data() + 3 * model.tet_node(t, c));
    volume += EdgeMatrix(xe).determinant() / 6.0;
  }
  EXPECT_NEAR(volume / (0.02 * 0.02 * 0.02), 1.0, 0.01);
  (void)probe;
}

/// A 20 mm cube of 6³ cells at ν = 0.45 resting on its clamped base, its
/// top pressed down by a point load at the centre: a tissue block under a
/// blade, with interior nodes whose patch term the factor only
/// approximates.
Model<double> PressedCube(int32_t* top) {
  const mesh::TetMesh mesh = testing::MakeBoxMesh(6, 6, 6, 0.02, 0.02, 0.02);
  const Material mat = Material::FromYoungPoisson(2e4, 0.45, 1000.0);
  ModelOptions opt;
  opt.element = ElementKind::kNodalPressure;
  Model<double> model(mesh, std::span(&mat, 1), opt);
  double best = 1e9;
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    const Eigen::Vector3d r = model.rest_position(n);
    if (r(2) < 1e-9) model.SetFixed(n, true);
    const double d = (r - Eigen::Vector3d(0.01, 0.01, 0.02)).norm();
    if (d < best) best = d, *top = n;
  }
  model.SetPrescribedForce(*top, Eigen::Vector3d(0, 0, -0.05));
  return model;
}

// The factor's lumped patch term (ImplicitOptions::patch_lumping) is a
// better preconditioner of the nodal-pressure Jacobian than its bare
// element-diagonal part: the same static step to the same tolerance takes
// fewer PCG iterations, and reaches the same state.
TEST(ImplicitNodalPressure, LumpedPatchTermPreconditionsInFewerIterations) {
  std::array<int, 2> iterations{};
  std::array<std::vector<double>, 2> x;
  for (int lumped = 0; lumped < 2; ++lumped) {
    int32_t top = -1;
    const Model<double> model = PressedCube(&top);
    State<double> state(model);
    ImplicitOptions o = Static();
    o.relative_force_tolerance = 1e-8;
    o.linear_tolerance = 1e-8;
    o.patch_lumping = lumped != 0 ? 0.5 : 0.0;
    ImplicitIntegrator integ(o);
    const ImplicitResult r = integ.Step(model, state, 100.0);
    ASSERT_TRUE(r.ok()) << "lumped " << lumped << ": residual " << r.residual;
    iterations[static_cast<size_t>(lumped)] = r.pcg_iterations;
    x[static_cast<size_t>(lumped)] = state.x;
  }
  EXPECT_LT(iterations[1], 0.85 * iterations[0]) << iterations[1] << " vs " << iterations[0];
  double diff = 0, size = 0;
  for (size_t i = 0; i < x[0].size(); ++i) {
    diff = std::max(diff, std::abs(x[0][i] - x[1][i]));
    size = std::max(size, std::abs(x[0][i]));
  }
  EXPECT_LT(diff, 1e-7 * size);
}

// The haptic stiffness of a point on the pressed cube, from the factor of
// the step (an approximation of the patch term, so P ≠ A): the estimate is
// accepted and predicts the static response to a small extra force within
// its 5 % error bound.
TEST(ImplicitNodalPressure, EffectiveStiffnessPredictsTheResponse) {
  int32_t top = -1;
  Model<double> model = PressedCube(&top);
  State<double> state(model);
  ImplicitOptions o = Static();
  o.relative_force_tolerance = 1e-9;
  ImplicitIntegrator integ(o);
  for (int k = 0; k < 2; ++k) {  // the second step assembles at the equilibrium
    std::fill(state.v.begin(), state.v.end(), 0.0);
    ASSERT_TRUE(integ.Step(model, state, 1e3).ok());
  }
  const int32_t nodes[1] = {top};
  const double weights[1] = {1.0};
  const Eigen::Matrix3d k_eff = integ.EffectiveStiffness(model, nodes, weights);
  ASSERT_FALSE(k_eff.isZero());
  EXPECT_LT((k_eff - k_eff.transpose()).norm(), 1e-9 * k_eff.norm());
  const Eigen::Vector3d df(1e-4, -2e-4, -3e-4);
  const std::vector<double> x_eq = state.x;
  model.SetPrescribedForce(top, Eigen::Vector3d(0, 0, -0.05) + df);
  std::fill(state.v.begin(), state.v.end(), 0.0);
  ASSERT_TRUE(integ.Step(model, state, 1e3).ok());
  const Eigen::Vector3d dx = Eigen::Map<const Eigen::Vector3d>(state.x.data() + 3 * top) -
                             Eigen::Map<const Eigen::Vector3d>(x_eq.data() + 3 * top);
  const Eigen::Vector3d predicted = k_eff.ldlt().solve(df);
  EXPECT_LT((dx - predicted).norm(), 5e-2 * dx.norm()) << "dx " << dx.transpose() << " predicted "
                                                         << predicted.transpose();
}

TEST(ImplicitNodalPressure, NodalAveragesAfterASplitEqualARebuild) {
  Model<double> model = Cantilever(0.45, ElementKind::kNodalPressure);
  model.reserve_nodes(model.num_nodes() + 4);
  State<double> state(model);
  int32_t mid = -1;
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    const Eigen::Vector3d r = model.rest_position(n);
    if (std::abs(r(0) - 0.03) < 1e-9 && std::abs(r(1) - 0.005) < 1e-9 && std::abs(r(2) - 0.01) < 1e-9) mid = n;
  }
  ASSERT_GE(mid, 0);
  ASSERT_GT(testing::SplitNodeAsACut(model, state, mid, [](const Vec3<double>& c) { return c(0) > 0.03; }), 0);
  std::vector<double> kappa(static_cast<size_t>(model.num_tets()));
  for (int32_t t = 0; t < model.num_tets(); ++t) kappa[static_cast<size_t>(t)] = model.kappas()[t];
  std::vector<double> node_kappa, node_volume;
  NodalRestVolumes(model, kappa, node_kappa, node_volume);
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    EXPECT_NEAR(model.node_rest_volume(n), node_volume[static_cast<size_t>(n)], 1e-18) << "node " << n;
    EXPECT_NEAR(model.node_kappa(n), node_kappa[static_cast<size_t>(n)], 1e-9 * node_kappa[static_cast<size_t>(n)]);
  }
  // And the split tissue still steps.
  State<double> s2(model);
  ImplicitIntegrator integ(Static());
  EXPECT_TRUE(integ.Step(model, s2, 0.01).ok());
}

}  // namespace
}  // namespace cutsim::fem
