// The preconditioner's pieces: the single-precision supernodal solve
// against the double solves, the low-rank correction of an old factor
// against a fresh factor of the cut matrix, PCG's deadline, the budgeted
// implicit step's residual report, and a refactorisation that never blocks
// a step.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "common/fem/implicit.h"
#include "common/fem/linear_solver.h"
#include "tests/unit/fem/implicit_fixtures.h"

namespace cutsim::fem {
namespace {

/// SPD matrix on the model's pattern: M/h² + K at the rest state, with
/// h = 10 ms (the implicit step's A/h²).
std::vector<double> SystemMatrix(ImplicitIntegrator& integ, const Model<double>& model) {
  std::vector<double> k;
  const std::vector<double> x = testing::DeformedPositions(model, 0, 1.0);
  integ.AssembleStiffness(model, x.data(), false, k);
  const SparseSystem& sys = integ.system();
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    sys.AddBlock(k.data(), sys.diagonal_block(n), n, 1e4 * model.node_mass(n) * Eigen::Matrix3d::Identity());
  }
  return k;
}

std::vector<double> Wave(int32_t n, double f) {
  std::vector<double> b(static_cast<size_t>(n));
  for (size_t i = 0; i < b.size(); ++i) b[i] = std::sin(f * static_cast<double>(i)) + 0.1;
  return b;
}

std::vector<double> Precondition(LinearSolver& solver, const SparseSystem& sys, const std::vector<double>& values,
                                 const std::vector<double>& r) {
  const std::vector<uint8_t> active(static_cast<size_t>(sys.num_nodes()), 1);
  std::vector<double> z(r.size());
  solver.Precondition(sys, values.data(), active.data(), r.data(), z.data());
  return z;
}

// The float solve agrees with CHOLMOD's double solve to a float's
// round-off times the factor's growth; the own double solve to round-off,
// and it inverts A.
TEST(SupernodalSolve, SingleAndDoubleAgreeWithCholmod) {
  Model<double> model = testing::MakeCantilever(12, 0.12, 3e4, false);
  ImplicitIntegrator integ;
  const std::vector<double> a = SystemMatrix(integ, model);
  const SparseSystem& sys = integ.system();
  const std::vector<double> r = Wave(sys.num_dofs(), 0.37);
  std::vector<std::vector<double>> z;
  for (const FactorSolve mode : {FactorSolve::kCholmod, FactorSolve::kDouble, FactorSolve::kFloat}) {
    LinearSolver solver(false, mode);
    solver.Resize(sys);
    ASSERT_TRUE(solver.RequestFactor(sys, a.data()));
    z.push_back(Precondition(solver, sys, a, r));
  }
  EXPECT_LT(testing::RelativeDifference(z[1], z[0]), 1e-12);
  const double float_error = testing::RelativeDifference(z[2], z[0]);
  EXPECT_LT(float_error, 1e-5);
  EXPECT_GT(float_error, 1e-12);  // it is a float solve
  std::vector<double> az(r.size());
  sys.MultiplyTeam(a.data(), z[1].data(), az.data());
  EXPECT_LT(testing::RelativeDifference(az, r), 1e-10);
}

/// The cantilever before and after a cut through the node at (x, y, z)
/// = (lx/2, 0.01, 0.01), and the nodes of every tet the cut changed.
struct CutFixture {
  Model<double> model = testing::MakeCantilever(8, 0.08, 3e4, false, 0, 0, 8);
  State<double> state{model};
  ImplicitIntegrator before, after;
  std::vector<double> a0, b;
  std::vector<int32_t> changed;
  int32_t old_dofs = 0;

  CutFixture() {
    a0 = SystemMatrix(before, model);
    old_dofs = before.system().num_dofs();
    std::vector<int32_t> tets_before(static_cast<size_t>(4 * model.num_tets()));
    for (int32_t t = 0; t < model.num_tets(); ++t) {
      for (int c = 0; c < 4; ++c) tets_before[static_cast<size_t>(4 * t + c)] = model.tet_node(t, c);
    }
    for (const double y : {0.0, 0.01, 0.02}) {
      for (const double z : {0.01, 0.02}) {
        const int32_t mid = testing::FindNode(model, 0.04, y, z);
        testing::SplitNodeAsACut(model, state, mid, [&](const Vec3<double>& c) { return c(0) > 0.04; });
      }
    }
    std::vector<uint8_t> mark(static_cast<size_t>(old_dofs / 3), 0);
    for (int32_t t = 0; t < model.num_tets(); ++t) {
      bool same = true;
      for (int c = 0; c < 4; ++c) same = same && tets_before[static_cast<size_t>(4 * t + c)] == model.tet_node(t, c);
      if (same) continue;
      for (int c = 0; c < 4; ++c) {
        const int32_t n = tets_before[static_cast<size_t>(4 * t + c)];
        mark[static_cast<size_t>(n)] = 1;
      }
    }
    for (int32_t n = 0; n < static_cast<int32_t>(mark.size()); ++n) {
      if (mark[static_cast<size_t>(n)] != 0) changed.push_back(n);
    }
    b = SystemMatrix(after, model);
  }
};

// Gives `solver` the factor of the matrix before the cut and sizes it for
// the cut one, as a step after a cut finds it.
void FactorBeforeTheCut(LinearSolver& solver, const CutFixture& f) {
  solver.Resize(f.before.system());
  ASSERT_TRUE(solver.RequestFactor(f.before.system(), f.a0.data()));
  solver.WaitForFactor();
  solver.Resize(f.after.system());
}

// Corrected for the changed and added DOFs, the old factor preconditions
// the cut matrix as a fresh factor of it does (to the float solve's
// round-off); without the correction it is far off.
TEST(FactorCorrection, EqualsAFreshFactorOfTheCutMatrix) {
  CutFixture f;
  const SparseSystem& sys = f.after.system();
  ASSERT_GT(sys.num_dofs(), f.old_dofs);
  ASSERT_FALSE(f.changed.empty());
  const std::vector<double> r = Wave(sys.num_dofs(), 0.21);

  LinearSolver fresh(false);
  fresh.Resize(sys);
  ASSERT_TRUE(fresh.RequestFactor(sys, f.b.data()));
  const std::vector<double> z_fresh = Precondition(fresh, sys, f.b, r);

  LinearSolver old(false);
  old.Resize(f.before.system());
  ASSERT_TRUE(old.RequestFactor(f.before.system(), f.a0.data()));
  old.Resize(sys);
  const std::vector<double> z_stale = Precondition(old, sys, f.b, r);
  ASSERT_EQ(old.CorrectFactor(sys, f.b.data(), f.changed, 10000), CorrectionStart::kStarted);
  EXPECT_EQ(old.correction_rank(), 3 * static_cast<int32_t>(f.changed.size()) + sys.num_dofs() - f.old_dofs);
  const std::vector<double> z_corrected = Precondition(old, sys, f.b, r);

  EXPECT_LT(testing::RelativeDifference(z_corrected, z_fresh), 1e-4);
  EXPECT_GT(testing::RelativeDifference(z_stale, z_fresh), 1e-2);

  // PCG with it converges in the iterations of a fresh factor.
  const std::vector<uint8_t> active(static_cast<size_t>(sys.num_nodes()), 1);
  std::vector<double> x(r.size());
  const PcgResult pr = old.Solve(sys, f.b.data(), active.data(), r.data(), x.data(), 1e-8, 100, 1);
  EXPECT_TRUE(pr.converged);
  EXPECT_LE(pr.iterations, 4);
}

// Above its rank cap the correction is refused and PCG falls back to the
// old factor on the old DOFs and block Jacobi on the new ones.
TEST(FactorCorrection, RefusedAboveItsRankAndPcgStillConverges) {
  CutFixture f;
  const SparseSystem& sys = f.after.system();
  LinearSolver old(false);
  old.Resize(f.before.system());
  ASSERT_TRUE(old.RequestFactor(f.before.system(), f.a0.data()));
  old.Resize(sys);
  EXPECT_EQ(old.CorrectFactor(sys, f.b.data(), f.changed, 6), CorrectionStart::kRefused);
  EXPECT_EQ(old.correction_rank(), 0);
  EXPECT_EQ(old.stats().corrections_refused, 1);
  const std::vector<double> r = Wave(sys.num_dofs(), 0.21);
  const std::vector<uint8_t> active(static_cast<size_t>(sys.num_nodes()), 1);
  std::vector<double> x(r.size());
  const PcgResult pr = old.Solve(sys, f.b.data(), active.data(), r.data(), x.data(), 1e-8, 500, 1);
  EXPECT_TRUE(pr.converged);
  EXPECT_GT(pr.iterations, 4);
}

// Columns that moved since the factor's values (a factor asked for at a cut
// sees the tissue there mid-transient) join the correction when they moved
// by more than the drift threshold: the corrected factor then equals a fresh
// factor again. Without them it does not, and PCG pays for it.
TEST(FactorCorrection, TakesTheColumnsThatMovedSinceTheFactor) {
  CutFixture f;
  const SparseSystem& sys = f.after.system();
  // Two nodes away from the cut stiffen fivefold on their diagonal blocks.
  std::vector<int32_t> moved;
  for (const double y : {0.0, 0.02}) {
    const int32_t node = testing::FindNode(f.model, 0.08, y, 0.02);
    ASSERT_FALSE(std::binary_search(f.changed.begin(), f.changed.end(), node));
    const int32_t off = sys.diagonal_block(node);
    const Eigen::Matrix3d block = sys.GetBlock(f.b.data(), off, node);
    sys.AddBlock(f.b.data(), off, node, 4.0 * Eigen::Matrix3d(block.diagonal().asDiagonal()));
    moved.push_back(node);
  }
  const std::vector<double> r = Wave(sys.num_dofs(), 0.21);
  const std::vector<uint8_t> active(static_cast<size_t>(sys.num_nodes()), 1);
  LinearSolver fresh(false);
  fresh.Resize(sys);
  ASSERT_TRUE(fresh.RequestFactor(sys, f.b.data()));
  const std::vector<double> z_fresh = Precondition(fresh, sys, f.b, r);

  const int32_t topology_rank = 3 * static_cast<int32_t>(f.changed.size()) + sys.num_dofs() - f.old_dofs;
  const auto corrected = [&](double drift, int32_t max_rank, int* iterations) {
    LinearSolver old(false);
    old.Resize(f.before.system());
    EXPECT_TRUE(old.RequestFactor(f.before.system(), f.a0.data()));
    old.Resize(sys);
    EXPECT_EQ(old.CorrectFactor(sys, f.b.data(), f.changed, max_rank, drift), CorrectionStart::kStarted);
    std::vector<double> x(r.size());
    *iterations = old.Solve(sys, f.b.data(), active.data(), r.data(), x.data(), 1e-8, 200, 1).iterations;
    return std::make_pair(Precondition(old, sys, f.b, r), old.stats().last_correction_drifted_nodes);
  };
  int topology_only_iterations = 0, with_drift_iterations = 0, capped_iterations = 0;
  const auto [z_topology, none] =
      corrected(std::numeric_limits<double>::infinity(), 10000, &topology_only_iterations);
  const auto [z_drift, drifted] = corrected(0.15, 10000, &with_drift_iterations);
  const auto [z_capped, capped] = corrected(0.15, topology_rank + 2, &capped_iterations);

  EXPECT_EQ(none, 0);
  EXPECT_GT(testing::RelativeDifference(z_topology, z_fresh), 1e-2);
  EXPECT_EQ(drifted, static_cast<int32_t>(moved.size())) << "the stiffened nodes and no others";
  EXPECT_LT(testing::RelativeDifference(z_drift, z_fresh), 1e-4);
  EXPECT_LE(with_drift_iterations, 4);
  EXPECT_GT(topology_only_iterations, with_drift_iterations);
  // Within the rank cap: the topology's DOFs first, no room for a drifted node.
  EXPECT_EQ(capped, 0);
  EXPECT_EQ(capped_iterations, topology_only_iterations);
}

// A deadline in the past stops PCG after its first iteration.
TEST(LinearSolverDeadline, StopsAtTheDeadlineWithTheIterateSoFar) {
  Model<double> model = testing::MakeCantilever(6, 0.06, 3e4, false);
  ImplicitIntegrator integ;
  const std::vector<double> a = SystemMatrix(integ, model);
  const SparseSystem& sys = integ.system();
  LinearSolver solver(false);
  solver.Resize(sys);
  // Block Jacobi only (no factor): many iterations to go.
  const std::vector<double> r = Wave(sys.num_dofs(), 0.5);
  const std::vector<uint8_t> active(static_cast<size_t>(sys.num_nodes()), 1);
  std::vector<double> x(r.size());
  const PcgResult pr = solver.Solve(sys, a.data(), active.data(), r.data(), x.data(), 1e-12, 500, 1, {}, nullptr, 1);
  EXPECT_TRUE(pr.out_of_time);
  EXPECT_FALSE(pr.converged);
  EXPECT_EQ(pr.iterations, 1);
  EXPECT_GT(*std::max_element(x.begin(), x.end()), 0.0);
}

// A step whose deadline has passed runs one Newton iteration, reports
// kOutOfTime with its residual in newtons, and advances the state; the
// next steps, without a deadline, take the carried residual down.
TEST(BudgetedStep, ReportsTheResidualItCarries) {
  Model<double> model = testing::MakeCantilever(6, 0.06, 3e4, true);
  State<double> state(model);
  ImplicitOptions options;
  options.asynchronous_factorization = false;
  options.relative_force_tolerance = 1e-9;
  options.carry_limit = 1e12;  // any residual may be carried
  ImplicitIntegrator integ(options);
  const ImplicitResult budgeted = integ.Step(model, state, 0.01, {}, 1);
  EXPECT_EQ(budgeted.status, ImplicitStatus::kOutOfTime);
  EXPECT_EQ(budgeted.newton_iterations, 1);
  EXPECT_GT(budgeted.residual, budgeted.tolerance);
  EXPECT_TRUE(budgeted.advanced());
  EXPECT_NEAR(state.time, 0.01, 1e-15);
  EXPECT_LT(budgeted.residual, budgeted.residual_history[0]);  // the one iteration made progress
  const ImplicitResult next = integ.Step(model, state, 0.01);
  EXPECT_EQ(next.status, ImplicitStatus::kConverged);
}

// Without an overrun limit a late step never carries more than
// carry_limit × the tolerance: it goes on past the deadline (over_budget)
// until its residual is within it.
/// A tight step with a carry limit of 1e3 × the tolerance and plain Newton
/// (one PCG solve does not converge it), with the given overrun limit.
ImplicitOptions LateStepOptions(double overrun_limit) {
  ImplicitOptions options;
  options.asynchronous_factorization = false;
  options.relative_force_tolerance = 1e-9;
  options.carry_limit = 1e3;
  options.overrun_limit = overrun_limit;
  options.tangent_reuse_contraction = 0;
  return options;
}

TEST(BudgetedStep, NeverCarriesMoreThanItsLimit) {
  Model<double> model = testing::MakeCantilever(6, 0.06, 3e4, true);
  State<double> state(model);
  const ImplicitOptions options = LateStepOptions(std::numeric_limits<double>::infinity());
  ImplicitIntegrator integ(options);
  const ImplicitResult r = integ.Step(model, state, 0.01, {}, 1);
  EXPECT_TRUE(r.over_budget);
  EXPECT_GT(r.newton_iterations, 1);
  EXPECT_LE(r.residual, options.carry_limit * r.tolerance);
  EXPECT_GT(r.residual_history[1], options.carry_limit * r.tolerance);  // it was late and above the limit
}

// With an overrun limit the same late step stops there whatever its
// residual: it reports over_budget and kOutOfTime with the residual it
// carries, above the carry limit, and the next steps take it down.
TEST(BudgetedStep, StopsAtItsOverrunLimitAndCarriesTheRest) {
  Model<double> model = testing::MakeCantilever(6, 0.06, 3e4, true);
  State<double> state(model);
  const ImplicitOptions options = LateStepOptions(1.0);  // the deadline has passed: so has the limit
  ImplicitIntegrator integ(options);
  const ImplicitResult r = integ.Step(model, state, 0.01, {}, 1);
  EXPECT_TRUE(r.over_budget);
  EXPECT_EQ(r.status, ImplicitStatus::kOutOfTime);
  EXPECT_EQ(r.newton_iterations, 1);
  EXPECT_GT(r.residual, options.carry_limit * r.tolerance);
  EXPECT_LT(r.residual, r.residual_history[0]);
  EXPECT_NEAR(state.time, 0.01, 1e-15);
  bool converged = false;
  for (int k = 0; k < 5 && !converged; ++k) converged = integ.Step(model, state, 0.01).ok();
  EXPECT_TRUE(converged);
}

// A velocity that, held over the step, would fold the body through its
// clamped end makes the first guess non-finite (the nodal-pressure
// element's volumetric energy is +∞ at J ≤ 0): Newton starts from the state
// itself and the step advances.
TEST(ImplicitRecovery, AnInvertingFirstGuessRestartsAtRest) {
  const mesh::TetMesh mesh = testing::MakeBoxMesh(6, 2, 2, 0.06, 0.02, 0.02);
  const Material mat = Material::FromYoungPoisson(3e4, 0.45, 1000.0, 0, 0);
  ModelOptions opt;
  opt.element = ElementKind::kNodalPressure;
  Model<double> model(mesh, std::span(&mat, 1), opt);
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    if (model.rest_position(n)(0) < 1e-9) model.SetFixed(n, true);
  }
  State<double> state(model);
  const double h = 0.01;
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    if (!model.fixed(n)) state.v[static_cast<size_t>(3 * n)] = -3.0 * model.rest_position(n)(0) / h;
  }
  ImplicitOptions options;
  options.asynchronous_factorization = false;
  options.force_tolerance = 1e-6;
  ImplicitIntegrator integ(options);
  const ImplicitResult r = integ.Step(model, state, h);
  EXPECT_TRUE(r.restarted_at_rest);
  EXPECT_TRUE(r.advanced());
  for (const double x : state.x) EXPECT_TRUE(std::isfinite(x));
}

// With a factorisation that takes a second, a step after a cut runs on the
// old factor and its correction and returns while the worker still
// factors: a refactorisation never blocks a step.
TEST(AsyncFactor, SlowRefactorisationNeverBlocksAStep) {
  Model<double> model = testing::MakeCantilever(8, 0.08, 3e4, true, 0, 0, 8);
  State<double> state(model);
  ImplicitOptions options;
  options.asynchronous_factorization = true;
  options.force_tolerance = 1e-7;
  ImplicitIntegrator integ(options);
  ASSERT_TRUE(integ.Step(model, state, 0.01).ok());  // waits for the first factor
  integ.mutable_linear_solver().WaitForFactor();     // the worker idle, its newest factor in use
  integ.mutable_linear_solver().set_worker_delay_for_testing(2.0);
  const int32_t original_nodes = model.num_nodes();
  for (int32_t n = 0; n < original_nodes; ++n) {
    const Vec3<double> p = model.rest_position(n);
    if (std::abs(p(0) - 0.04) < 1e-9 && p(2) > 0.005) {
      testing::SplitNodeAsACut(model, state, n, [](const Vec3<double>& c) { return c(0) > 0.04; });
    }
  }
  const ImplicitResult r = integ.Step(model, state, 0.01);
  EXPECT_TRUE(r.pattern_rebuilt);
  EXPECT_TRUE(r.factor_requested);
  EXPECT_TRUE(r.correction_started);
  EXPECT_EQ(r.status, ImplicitStatus::kConverged)
      << r.newton_iterations << " Newton, " << r.pcg_iterations << " PCG, residual " << r.residual << " N, tolerance "
      << r.tolerance << " N, halvings " << r.line_search_halvings;
  EXPECT_TRUE(integ.linear_solver().busy());  // the new factor is still being made
  EXPECT_TRUE(integ.linear_solver().correcting());  // and so is the correction
  EXPECT_EQ(integ.linear_solver().correction_rank(), 0);
  EXPECT_LT(r.factor_dofs, integ.system().num_dofs());
  integ.mutable_linear_solver().WaitForCorrection();
  EXPECT_EQ(integ.linear_solver().stats().corrections, 1);
  integ.mutable_linear_solver().WaitForFactor();
}

// The correction built on its own thread is the one built inline, and the
// solves take it up at their next Acquire.
TEST(AsyncFactor, CorrectionOnItsThreadEqualsTheInlineOne) {
  CutFixture f;
  const SparseSystem& sys = f.after.system();
  const std::vector<double> r = Wave(sys.num_dofs(), 0.21);
  const auto corrected = [&](bool asynchronous) {
    LinearSolver solver(asynchronous);
    FactorBeforeTheCut(solver, f);
    EXPECT_EQ(solver.CorrectFactor(sys, f.b.data(), f.changed, 10000, 0.15), CorrectionStart::kStarted);
    solver.WaitForCorrection();
    EXPECT_FALSE(solver.correcting());
    EXPECT_GT(solver.correction_rank(), 0);
    return Precondition(solver, sys, f.b, r);
  };
  const std::vector<double> z_inline = corrected(false);
  const std::vector<double> z_thread = corrected(true);
  EXPECT_LT(testing::RelativeDifference(z_thread, z_inline), 1e-12);
}

// A solve started before the correction lands takes it up when it does
// (or not, as the threads run): either way PCG converges to A x = b.
TEST(AsyncFactor, ASolveBesideACorrectionInTheMakingConverges) {
  CutFixture f;
  const SparseSystem& sys = f.after.system();
  const std::vector<double> r = Wave(sys.num_dofs(), 0.21);
  const std::vector<uint8_t> active(static_cast<size_t>(sys.num_nodes()), 1);
  for (int trial = 0; trial < 5; ++trial) {
    LinearSolver solver(true);
    FactorBeforeTheCut(solver, f);
    ASSERT_EQ(solver.CorrectFactor(sys, f.b.data(), f.changed, 10000, 0.15), CorrectionStart::kStarted);
    std::vector<double> x(r.size());
    const PcgResult pr = solver.Solve(sys, f.b.data(), active.data(), r.data(), x.data(), 1e-9, 2000, 1);
    EXPECT_TRUE(pr.converged) << pr.iterations << " iterations, residual " << pr.residual;
    std::vector<double> ax(r.size(), 0.0);
    sys.MultiplyTeam(f.b.data(), x.data(), ax.data());
    double misfit = 0;
    for (size_t i = 0; i < r.size(); ++i) misfit += (ax[i] - r[i]) * (ax[i] - r[i]);
    EXPECT_LT(std::sqrt(misfit), 1e-8);
    solver.WaitForCorrection();
    EXPECT_EQ(solver.stats().corrections, 1);
  }
}

// While the thread builds one correction, another is not taken (kBusy):
// the caller asks again later.
TEST(AsyncFactor, ABusyCorrectionThreadTakesNoSecondJob) {
  CutFixture f;
  const SparseSystem& sys = f.after.system();
  LinearSolver solver(true);
  FactorBeforeTheCut(solver, f);
  solver.set_worker_delay_for_testing(1.0);
  ASSERT_EQ(solver.CorrectFactor(sys, f.b.data(), f.changed, 10000), CorrectionStart::kStarted);
  EXPECT_EQ(solver.CorrectFactor(sys, f.b.data(), f.changed, 10000), CorrectionStart::kBusy);
  solver.set_worker_delay_for_testing(0);
  solver.WaitForCorrection();
  EXPECT_EQ(solver.stats().corrections, 1);
  EXPECT_EQ(solver.CorrectFactor(sys, f.b.data(), f.changed, 10000), CorrectionStart::kStarted);
  solver.WaitForCorrection();
  EXPECT_EQ(solver.stats().corrections, 2);
}

// The worker factors on its own thread alone: the OpenMP regions inside
// CHOLMOD may not take the step team's core. Synchronous factors, which the
// step waits for anyway, may use every thread.
TEST(AsyncFactor, TheWorkerFactorsOnOneThread) {
  Model<double> model = testing::MakeCantilever(8, 0.08, 3e4, true, 0, 0, 8);
  ImplicitIntegrator integ;
  const std::vector<double> a = SystemMatrix(integ, model);
  const SparseSystem& sys = integ.system();
  LinearSolver worker(true);
  worker.Resize(sys);
  ASSERT_TRUE(worker.RequestFactor(sys, a.data()));
  worker.WaitForFactor();
  EXPECT_EQ(worker.stats().factor_thread_limit, 1);
  LinearSolver inline_solver(false);
  inline_solver.Resize(sys);
  ASSERT_TRUE(inline_solver.RequestFactor(sys, a.data()));
  EXPECT_GT(inline_solver.stats().factor_thread_limit, 1);
}

}  // namespace
}  // namespace cutsim::fem
