// The backward Euler step: Newton's convergence, the static equilibrium
// against the explicit path brought to rest, energy decay, determinism,
// stale factors and topology changes, compression, penalty springs and the
// effective stiffness.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "common/fem/forces.h"
#include "common/fem/implicit.h"
#include "common/fem/integrator.h"
#include "tests/unit/fem/energy_util.h"
#include "tests/unit/fem/implicit_fixtures.h"

namespace cutsim::fem {
namespace {

using testing::TotalEnergy;

/// Synchronous factorisation (reproducible), tight linear solves.
ImplicitOptions Tight(double relative_tolerance = 1e-10) {
  ImplicitOptions o;
  o.asynchronous_factorization = false;
  o.relative_force_tolerance = relative_tolerance;
  o.linear_tolerance = 1e-10;
  o.max_newton_iterations = 40;
  return o;
}

/// Relative L2 distance of the displacements of a and b from rest.
double RelativeDisplacementError(const Model<double>& model, const std::vector<double>& a,
                                 const std::vector<double>& b) {
  double num = 0, den = 0;
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    for (int d = 0; d < 3; ++d) {
      const auto i = static_cast<size_t>(3 * n + d);
      const double ua = a[i] - model.rest_position(n)(d);
      num += (a[i] - b[i]) * (a[i] - b[i]);
      den += ua * ua;
    }
  }
  return std::sqrt(num / den);
}

/// Tip node: the free corner at (lx, 0.02, 0.02).
int32_t TipNode(const Model<double>& model) {
  int32_t best = 0;
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    if (model.rest_position(n).sum() > model.rest_position(best).sum()) best = n;
  }
  return best;
}

// A step much longer than the slowest period is a static solve; with the
// exact Jacobian Newton's residual falls quadratically near the solution.
TEST(ImplicitStep, NewtonConvergesQuadraticallyOnAStaticCase) {
  const Model<double> model = testing::MakeCantilever(6, 0.06, 1e5);
  State<double> state(model);
  ImplicitOptions opt = Tight(1e-11);
  opt.tangent = TangentMode::kExact;
  opt.tangent_reuse_contraction = 0;  // plain Newton
  ImplicitIntegrator integ(opt);
  const ImplicitResult r = integ.Step(model, state, 100.0);
  ASSERT_TRUE(r.ok()) << "residual " << r.residual << " after " << r.newton_iterations;
  EXPECT_LE(r.newton_iterations, 12);
  const double scale = r.tolerance / 1e-11;
  EXPECT_TRUE(testing::HasQuadraticStep(r, scale));
  EXPECT_EQ(r.line_search_halvings, 0);
}

// The static equilibrium matches the explicit integrator brought to rest by
// mass damping on the same mesh.
TEST(ImplicitStep, StaticEquilibriumMatchesExplicitAtRest) {
  const Model<double> model = testing::MakeCantilever(6, 0.06, 1e5);
  State<double> implicit_state(model);
  ImplicitIntegrator integ(Tight(1e-11));
  ASSERT_TRUE(integ.Step(model, implicit_state, 100.0).ok());

  State<double> explicit_state(model);
  StepOptions eo;
  eo.mass_damping = 110.0;  // about critical for the first bending mode
  eo.num_threads = 1;
  for (int frame = 0; frame < 200; ++frame) ASSERT_TRUE(Advance(model, explicit_state, 0.01, eo).ok());
  EXPECT_LT(KineticEnergy(model, explicit_state.v.data()), 1e-18);
  const double err = RelativeDisplacementError(model, explicit_state.x, implicit_state.x);
  EXPECT_LT(err, 1e-4);
  // And the sag is real (a few mm).
  const int32_t tip = TipNode(model);
  EXPECT_LT(implicit_state.x[static_cast<size_t>(3 * tip + 2)] - 0.02, -1e-3);
}

// Reusing the tangent changes how Newton gets there, not where: a dynamic
// run that reuses K ends where plain Newton does, within what the force
// tolerance allows, and assembles K fewer times than it iterates.
TEST(ImplicitStep, TangentReuseReachesTheSameStates) {
  const Model<double> model = testing::MakeCantilever(6, 0.06, 1e5);
  ImplicitOptions plain = Tight(1e-9);
  plain.linear_tolerance = 1e-3;
  plain.tangent_reuse_contraction = 0;
  ImplicitOptions reuse = plain;
  reuse.tangent_reuse_contraction = 0.25;
  State<double> a(model), b(model);
  ImplicitIntegrator ia(plain), ib(reuse);
  int newton_a = 0, assemblies_a = 0, newton_b = 0, assemblies_b = 0;
  for (int step = 0; step < 20; ++step) {
    const ImplicitResult ra = ia.Step(model, a, 0.01);
    const ImplicitResult rb = ib.Step(model, b, 0.01);
    ASSERT_TRUE(ra.ok() && rb.ok()) << "step " << step;
    newton_a += ra.newton_iterations;
    assemblies_a += ra.tangent_assemblies;
    newton_b += rb.newton_iterations;
    assemblies_b += rb.tangent_assemblies;
  }
  EXPECT_EQ(assemblies_a, newton_a);
  EXPECT_LT(assemblies_b, newton_b);
  EXPECT_LT(RelativeDisplacementError(model, a.x, b.x), 1e-6);
}

// Undamped backward Euler never gains energy (kinetic + strain + gravity),
// beyond the work the residual tolerance allows.
TEST(ImplicitStep, UndampedEnergyNeverIncreases) {
  const Model<double> model = testing::MakeCantilever(6, 0.06, 1e5);
  State<double> state(model);
  ImplicitIntegrator integ(Tight(1e-9));
  double e = TotalEnergy(model, state);
  const double e0 = e;
  for (int step = 0; step < 30; ++step) {
    const std::vector<double> x_before = state.x;
    const ImplicitResult r = integ.Step(model, state, 0.01);
    ASSERT_TRUE(r.ok()) << "step " << step;
    double slack = 0;
    for (int32_t n = 0; n < model.num_nodes(); ++n) {
      double d2 = 0;
      for (int d = 0; d < 3; ++d) {
        const auto i = static_cast<size_t>(3 * n + d);
        d2 += (state.x[i] - x_before[i]) * (state.x[i] - x_before[i]);
      }
      slack += r.tolerance * std::sqrt(d2);
    }
    const double e_next = TotalEnergy(model, state);
    EXPECT_LE(e_next, e + slack + 1e-15 * std::abs(e)) << "step " << step;
    e = e_next;
  }
  EXPECT_LT(e, e0);  // it fell and lost energy to the scheme's dissipation
}

/// Copies the tip by a vertex split: tets on the +x side of a middle node
/// move to a copy of it (as cutting does).
void SplitMiddleNode(Model<double>& model, State<double>& state) {
  int32_t mid = -1;
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    const Vec3<double> p = model.rest_position(n);
    if (std::abs(p(0) - 0.03) < 1e-9 && std::abs(p(1) - 0.01) < 1e-9 && std::abs(p(2) - 0.01) < 1e-9) mid = n;
  }
  ASSERT_GE(mid, 0);
  const Vec3<double> p = model.rest_position(mid);
  ASSERT_GT(testing::SplitNodeAsACut(model, state, mid,
                                     [&](const Vec3<double>& c) { return c(0) > p(0) && c(2) > p(2); }),
            0);
}

TEST(ImplicitStep, OneThreadEqualsTwoThreads) {
  const Model<double> model = testing::MakeCantilever(16, 0.16, 3e5, true, 5.0, 20.0);
  State<double> s1(model), s2(model);
  ImplicitOptions o = Tight(1e-8);
  o.mass_damping = 2.0;
  o.num_threads = 1;
  ImplicitIntegrator one(o);
  o.num_threads = 2;
  ImplicitIntegrator two(o);
  PenaltyTerm pen;
  pen.nodes = {TipNode(model), -1, -1};
  pen.weights = {1.0, 0, 0};
  pen.stiffness = 50.0 * Eigen::Matrix3d::Identity();
  pen.force = Eigen::Vector3d(0, 0, 0.01);
  for (int step = 0; step < 3; ++step) {
    ASSERT_TRUE(one.Step(model, s1, 0.01, std::span(&pen, 1)).ok());
    ASSERT_TRUE(two.Step(model, s2, 0.01, std::span(&pen, 1)).ok());
  }
  EXPECT_EQ(s1.x, s2.x);
  EXPECT_EQ(s1.v, s2.v);
}

// A factor kept through a change of h and load (never refreshed) still
// preconditions PCG to the same solution a fresh factor gives.
TEST(ImplicitStep, StaleFactorStillConverges) {
  const Model<double> model = testing::MakeCantilever(6, 0.06, 3e4, true, 5.0, 20.0);
  State<double> stale_state(model);
  ImplicitOptions o = Tight(1e-9);
  o.refactor_pcg_iterations = 1 << 20;  // the first factor stays in use
  ImplicitIntegrator stale(o);
  ASSERT_TRUE(stale.Step(model, stale_state, 0.005).ok());
  State<double> fresh_state = stale_state;
  for (int step = 0; step < 4; ++step) {
    const ImplicitResult r = stale.Step(model, stale_state, 0.02);
    ASSERT_TRUE(r.ok()) << "step " << step;
    EXPECT_FALSE(r.factor_requested);
  }
  ImplicitIntegrator fresh(Tight(1e-9));
  for (int step = 0; step < 4; ++step) {
    ImplicitIntegrator one_off(Tight(1e-9));  // a new factor every step
    ASSERT_TRUE(one_off.Step(model, fresh_state, 0.02).ok());
  }
  EXPECT_LT(RelativeDisplacementError(model, stale_state.x, fresh_state.x), 1e-6);
}

TEST(ImplicitStep, TopologyChangeRebuildsThePatternAndConverges) {
  for (const bool async : {false, true}) {
    Model<double> model = testing::MakeCantilever(6, 0.06, 3e4, true, 5.0, 20.0, 8);
    State<double> state(model);
    ImplicitOptions o = Tight(1e-9);
    o.asynchronous_factorization = async;
    ImplicitIntegrator integ(o);
    for (int step = 0; step < 3; ++step) ASSERT_TRUE(integ.Step(model, state, 0.01).ok());
    const int64_t builds = integ.system().builds();
    SplitMiddleNode(model, state);
    State<double> reference = state;
    const ImplicitResult r = integ.Step(model, state, 0.01);
    ASSERT_TRUE(r.ok()) << "async " << async;
    EXPECT_TRUE(r.pattern_rebuilt);
    EXPECT_EQ(integ.system().builds(), builds + 1);
    EXPECT_EQ(integ.system().num_nodes(), model.num_nodes());
    ImplicitIntegrator fresh(Tight(1e-9));
    ASSERT_TRUE(fresh.Step(model, reference, 0.01).ok());
    EXPECT_LT(RelativeDisplacementError(model, state.x, reference.x), 1e-6) << "async " << async;
    for (int step = 0; step < 3; ++step) ASSERT_TRUE(integ.Step(model, state, 0.01).ok());
  }
}

// Compression makes S indefinite: the exact, clamped and automatic tangents
// all reach the same equilibrium; only the clamped one uses K⁺.
TEST(ImplicitStep, CompressedBlockConvergesWithEveryTangentMode) {
  Model<double> model = testing::MakeCantilever(2, 0.02, 3e4, false);
  int loaded = 0;
  for (int32_t n = 0; n < model.num_nodes(); ++n) loaded += model.rest_position(n)(0) > 0.02 - 1e-9 ? 1 : 0;
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    if (model.rest_position(n)(0) > 0.02 - 1e-9) model.SetPrescribedForce(n, Vec3<double>(-1.0 / loaded, 0, 0));
  }
  std::vector<std::vector<double>> solutions;
  for (const TangentMode mode : {TangentMode::kExact, TangentMode::kClamped, TangentMode::kAuto}) {
    State<double> state(model);
    ImplicitOptions o = Tight(1e-10);
    o.tangent = mode;
    ImplicitIntegrator integ(o);
    const ImplicitResult r = integ.Step(model, state, 100.0);
    ASSERT_TRUE(r.ok()) << "mode " << static_cast<int>(mode) << " residual " << r.residual;
    EXPECT_EQ(r.clamped, mode == TangentMode::kClamped);
    solutions.push_back(state.x);
    // The loaded face moves in visibly.
    EXPECT_LT(state.x[static_cast<size_t>(3 * TipNode(model))], 0.02 * 0.97);
  }
  EXPECT_LT(RelativeDisplacementError(model, solutions[0], solutions[1]), 1e-7);
  EXPECT_LT(RelativeDisplacementError(model, solutions[0], solutions[2]), 1e-7);
}

// A penalty term without stiffness is a nodal force; with stiffness it
// holds its point.
TEST(ImplicitStep, PenaltyTermsEnterResidualAndJacobian) {
  Model<double> model = testing::MakeCantilever(6, 0.06, 1e5);
  const int32_t tip = TipNode(model);
  PenaltyTerm pen;
  pen.nodes = {tip, -1, -1};
  pen.weights = {1.0, 0, 0};
  pen.force = Eigen::Vector3d(0, 0, 0.02);
  State<double> with_pen(model);
  ImplicitIntegrator a(Tight(1e-11));
  ASSERT_TRUE(a.Step(model, with_pen, 100.0, std::span(&pen, 1)).ok());
  model.SetPrescribedForce(tip, pen.force);
  State<double> with_force(model);
  ImplicitIntegrator b(Tight(1e-11));
  ASSERT_TRUE(b.Step(model, with_force, 100.0).ok());
  EXPECT_LT(RelativeDisplacementError(model, with_pen.x, with_force.x), 1e-8);
  model.SetPrescribedForce(tip, Vec3<double>::Zero());

  // A stiff spring on a face triangle of the tip holds that point near its
  // start while gravity pulls the rest down.
  PenaltyTerm hold;
  hold.nodes = {tip, tip - 1, tip - 3};
  hold.weights = {0.5, 0.25, 0.25};
  hold.stiffness = 1e4 * Eigen::Matrix3d::Identity();
  State<double> held(model);
  ImplicitIntegrator c(Tight(1e-11));
  const ImplicitResult r = c.Step(model, held, 100.0, std::span(&hold, 1));
  ASSERT_TRUE(r.ok()) << "residual " << r.residual << " tolerance " << r.tolerance << " after "
                      << r.newton_iterations << " halvings " << r.line_search_halvings;
  EXPECT_LE(r.newton_iterations, 12);
  Eigen::Vector3d p = Eigen::Vector3d::Zero(), p0 = Eigen::Vector3d::Zero();
  for (int i = 0; i < 3; ++i) {
    const auto n = static_cast<size_t>(hold.nodes[static_cast<size_t>(i)]);
    p += hold.weights[static_cast<size_t>(i)] * Eigen::Vector3d(held.x[3 * n], held.x[3 * n + 1], held.x[3 * n + 2]);
    p0 += hold.weights[static_cast<size_t>(i)] * model.rest_position(static_cast<int32_t>(n));
  }
  EXPECT_LT((p - p0).norm(), 2e-4);
}

// The effective stiffness predicts the static response to a small force.
TEST(ImplicitStep, EffectiveStiffnessPredictsTheResponse) {
  Model<double> model = testing::MakeCantilever(6, 0.06, 1e5);
  const int32_t tip = TipNode(model);
  State<double> state(model);
  ImplicitIntegrator integ(Tight(1e-10));
  const ImplicitResult r0 = integ.Step(model, state, 1e3);
  ASSERT_TRUE(r0.ok()) << "residual " << r0.residual << " tolerance " << r0.tolerance << " after "
                       << r0.newton_iterations << " halvings " << r0.line_search_halvings;
  std::fill(state.v.begin(), state.v.end(), 0.0);
  ASSERT_TRUE(integ.Step(model, state, 1e3).ok());  // assembled at the equilibrium
  const int32_t nodes[1] = {tip};
  const double weights[1] = {1.0};
  const Eigen::Matrix3d k_eff = integ.EffectiveStiffness(model, nodes, weights);
  EXPECT_LT((k_eff - k_eff.transpose()).norm(), 1e-6 * k_eff.norm());
  EXPECT_GT(k_eff.eigenvalues().real().minCoeff(), 0.0);
  const Eigen::Vector3d df(1e-4, -2e-4, 3e-4);
  const std::vector<double> x_eq = state.x;
  model.SetPrescribedForce(tip, df);
  std::fill(state.v.begin(), state.v.end(), 0.0);
  ASSERT_TRUE(integ.Step(model, state, 1e3).ok());
  const Eigen::Vector3d dx(state.x[static_cast<size_t>(3 * tip)] - x_eq[static_cast<size_t>(3 * tip)],
                           state.x[static_cast<size_t>(3 * tip + 1)] - x_eq[static_cast<size_t>(3 * tip + 1)],
                           state.x[static_cast<size_t>(3 * tip + 2)] - x_eq[static_cast<size_t>(3 * tip + 2)]);
  const Eigen::Vector3d predicted = k_eff.ldlt().solve(df);
  EXPECT_LT((dx - predicted).norm(), 1e-2 * predicted.norm());
}

// The effective stiffness comes from the preconditioner in use (a Galerkin
// estimate on its block Krylov space). The beam hangs bent under gravity
// and a tip load with a factor refreshed only after 40 PCG iterations
// (staler than the steps' default): the estimate predicts the static
// response to a small force. With the factor made once, at rest, it is
// either that accurate or refused (zero: the caller keeps an earlier one),
// never a wrong stiffness.
TEST(ImplicitStep, EffectiveStiffnessFromAStaleFactorPredictsTheResponse) {
  for (const int refactor_after : {40, 1 << 20}) {
    SCOPED_TRACE(refactor_after);
    Model<double> model = testing::MakeCantilever(6, 0.06, 1e5);
    const int32_t tip = TipNode(model);
    State<double> state(model);
    ImplicitOptions o = Tight(1e-10);
    o.refactor_pcg_iterations = refactor_after;
    o.max_pcg_iterations = 2000;
    ImplicitIntegrator integ(o);
    ASSERT_TRUE(integ.Step(model, state, 1e3).ok());
    const Eigen::Vector3d load(0, 0.02, -0.03);
    model.SetPrescribedForce(tip, load);
    for (int k = 0; k < 2; ++k) {
      std::fill(state.v.begin(), state.v.end(), 0.0);
      ASSERT_TRUE(integ.Step(model, state, 1e3).ok());
    }
    const int64_t factors = integ.linear_solver().stats().completed;
    const int32_t nodes[1] = {tip};
    const double weights[1] = {1.0};
    const Eigen::Matrix3d k_eff = integ.EffectiveStiffness(model, nodes, weights);
    if (refactor_after == 40) {
      EXPECT_GT(factors, 1);
      ASSERT_FALSE(k_eff.isZero());
    } else {
      EXPECT_EQ(factors, 1);  // made at the first iterate, at rest
      if (k_eff.isZero()) continue;  // refused
    }
    EXPECT_LT((k_eff - k_eff.transpose()).norm(), 1e-9 * k_eff.norm());
    EXPECT_GT(k_eff.eigenvalues().real().minCoeff(), 0.0);
    const Eigen::Vector3d df(1e-4, -2e-4, 3e-4);
    const std::vector<double> x_eq = state.x;
    model.SetPrescribedForce(tip, load + df);
    std::fill(state.v.begin(), state.v.end(), 0.0);
    ASSERT_TRUE(integ.Step(model, state, 1e3).ok());
    const Eigen::Vector3d dx = Eigen::Map<const Eigen::Vector3d>(state.x.data() + 3 * tip) -
                               Eigen::Map<const Eigen::Vector3d>(x_eq.data() + 3 * tip);
    const Eigen::Vector3d predicted = k_eff.ldlt().solve(df);
    EXPECT_LT((dx - predicted).norm(), 1e-2 * predicted.norm());
  }
}

// While the factor lags a cut (its worker is slowed down here) it is not
// current, and the effective stiffness, from the corrected factor, still
// predicts the static response or is refused; once the factor of the new
// pattern lands it is current again.
TEST(ImplicitStep, FactorIsCurrentOnceTheFactorOfACutLands) {
  Model<double> model = testing::MakeCantilever(6, 0.06, 3e4, true, 5.0, 20.0, 8);
  const int32_t tip = TipNode(model);
  State<double> state(model);
  ImplicitOptions o = Tight(1e-9);
  o.asynchronous_factorization = true;
  ImplicitIntegrator integ(o);
  for (int step = 0; step < 3; ++step) ASSERT_TRUE(integ.Step(model, state, 0.01).ok());
  integ.mutable_linear_solver().WaitForFactor();
  EXPECT_TRUE(integ.FactorIsCurrent());
  integ.mutable_linear_solver().set_worker_delay_for_testing(0.5);
  SplitMiddleNode(model, state);
  ASSERT_TRUE(integ.Step(model, state, 0.01).advanced());
  EXPECT_FALSE(integ.FactorIsCurrent());
  const int32_t nodes[1] = {tip};
  const double weights[1] = {1.0};
  const Eigen::Matrix3d k_lagging = integ.EffectiveStiffness(model, nodes, weights);
  integ.mutable_linear_solver().WaitForFactor();
  EXPECT_TRUE(integ.FactorIsCurrent());
  const Eigen::Matrix3d k_current = integ.EffectiveStiffness(model, nodes, weights);
  ASSERT_FALSE(k_current.isZero());
  if (!k_lagging.isZero()) {
    EXPECT_LT((k_lagging - k_current).norm(), 0.1 * k_current.norm());
  }
}

// BDF2 converges at second order in h, backward Euler at first: halving h
// divides the error at a fixed time by about 4 and 2 respectively.
TEST(ImplicitStep, Bdf2IsSecondOrderAndBackwardEulerFirst) {
  const Model<double> model = testing::MakeCantilever(4, 0.04, 3e4);
  const double t_end = 0.04;
  const auto run = [&](bool bdf2, int steps) {
    State<double> state(model);
    ImplicitOptions o = Tight(1e-11);
    o.bdf2 = bdf2;
    ImplicitIntegrator integ(o);
    for (int k = 0; k < steps; ++k) {
      const ImplicitResult r = integ.Step(model, state, t_end / steps);
      EXPECT_TRUE(r.ok());
      EXPECT_EQ(r.bdf2, bdf2 && k > 0);
    }
    return state.x;
  };
  const std::vector<double> reference = run(true, 128);
  const auto error = [&](const std::vector<double>& x) {
    double e = 0;
    for (int32_t i = 0; i < 3 * model.num_nodes(); ++i) {
      e += (x[static_cast<size_t>(i)] - reference[static_cast<size_t>(i)]) *
           (x[static_cast<size_t>(i)] - reference[static_cast<size_t>(i)]);
    }
    return std::sqrt(e);
  };
  const double bdf2_coarse = error(run(true, 8)), bdf2_fine = error(run(true, 16));
  const double be_coarse = error(run(false, 8)), be_fine = error(run(false, 16));
  EXPECT_GT(bdf2_coarse / bdf2_fine, 3.0) << bdf2_coarse << " " << bdf2_fine;
  EXPECT_LT(be_coarse / be_fine, 2.6) << be_coarse << " " << be_fine;
  EXPECT_GT(be_coarse / be_fine, 1.5);
  EXPECT_LT(bdf2_fine, be_fine);
}

TEST(ImplicitStep, BadTimeStepIsReportedNotThrown) {
  const Model<double> model = testing::MakeCantilever(2, 0.02, 3e4);
  State<double> state(model);
  ImplicitIntegrator integ;
  EXPECT_EQ(integ.Step(model, state, -1.0).status, ImplicitStatus::kNonFinite);
  EXPECT_EQ(integ.Step(model, state, std::nan("")).status, ImplicitStatus::kNonFinite);
  EXPECT_EQ(state.step, 0);
}

}  // namespace
}  // namespace cutsim::fem
