// A steady-state implicit step must not touch the heap (allocations counted
// by tests/support/malloc_counter.h).
#include <gtest/gtest.h>

#include "common/fem/implicit.h"
#include "tests/support/malloc_counter.h"
#include "tests/unit/fem/implicit_fixtures.h"

namespace cutsim::fem {
namespace {

void ExpectNoAllocation(bool bdf2) {
#ifdef CUTSIM_COUNT_MALLOC
  const Model<double> model = testing::MakeCantilever(4, 0.04, 3e4, true, 5.0, 20.0);
  State<double> state(model);
  ImplicitOptions opt;
  opt.num_threads = 2;
  opt.asynchronous_factorization = false;
  opt.refactor_pcg_iterations = 1 << 30;  // keep the first factor: no CHOLMOD work
  opt.mass_damping = 1.0;
  opt.bdf2 = bdf2;
  ImplicitIntegrator integ(opt);
  PenaltyTerm pen;
  pen.nodes = {model.num_nodes() - 1, -1, -1};
  pen.weights = {1.0, 0, 0};
  pen.stiffness = 20.0 * Eigen::Matrix3d::Identity();
  // Warm-up: pattern, first factor, CHOLMOD's solve workspace, OpenMP team.
  ASSERT_TRUE(integ.Step(model, state, 0.01, std::span(&pen, 1)).ok());
  ASSERT_TRUE(integ.Step(model, state, 0.01, std::span(&pen, 1)).ok());
  support::StartCountingAllocations();
  const ImplicitResult r = integ.Step(model, state, 0.01, std::span(&pen, 1));
  const long allocations = support::StopCountingAllocations();
  ASSERT_TRUE(r.ok());
  EXPECT_GT(r.newton_iterations, 0);
  EXPECT_EQ(r.bdf2, bdf2);
  EXPECT_EQ(allocations, 0);
#else
  (void)bdf2;
  GTEST_SKIP() << "malloc interposition unavailable (sanitizer build)";
#endif
}

TEST(ImplicitAlloc, SteadyStateBackwardEulerStepDoesNotAllocate) { ExpectNoAllocation(false); }
TEST(ImplicitAlloc, SteadyStateBdf2StepDoesNotAllocate) { ExpectNoAllocation(true); }

}  // namespace
}  // namespace cutsim::fem
