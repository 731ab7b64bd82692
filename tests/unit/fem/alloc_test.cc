// A step must not touch the heap (allocations counted by
// tests/support/malloc_counter.h).
#include <gtest/gtest.h>

#include "common/fem/integrator.h"
#include "common/fem/model.h"
#include "common/fem/state.h"
#include "tests/support/malloc_counter.h"
#include "tests/unit/fem/test_meshes.h"

namespace cutsim::fem {
namespace {

template <typename T>
void ExpectNoAllocation(ViscousTreatment viscous) {
#ifdef CUTSIM_COUNT_MALLOC
  const mesh::TetMesh mesh = testing::MakeBoxMesh(4, 3, 3, 0.04, 0.03, 0.03);
  const Material mat{.lambda = 140000, .mu = 11000, .psi = 10, .phi = 80, .density = 1000};
  Model<T> model(mesh, std::span(&mat, 1), {.gravity = Eigen::Vector3d(0, 0, -9.81)});
  for (int n = 0; n < 16; ++n) model.SetFixed(n, true);
  State<T> state(model);
  StepOptions opt;
  opt.num_threads = 2;
  opt.viscous = viscous;
  opt.dt_refresh_interval = 3;  // exercise the refresh inside Advance too
  // Warm-up: OpenMP creates its thread team on first use.
  ASSERT_TRUE(Advance(model, state, 1e-4, opt).ok());
  support::StartCountingAllocations();
  const StepResult r = Advance(model, state, 2e-4, opt);
  const StepResult r2 = Step(model, state, T(1e-6), opt);
  const long allocations = support::StopCountingAllocations();
  ASSERT_TRUE(r.ok());
  ASSERT_TRUE(r2.ok());
  EXPECT_GT(r.substeps, 1);  // several substeps, refreshes included
  EXPECT_EQ(allocations, 0);
#else
  (void)viscous;
  GTEST_SKIP() << "malloc interposition unavailable (sanitizer build)";
#endif
}

TEST(FemAlloc, StepDoesNotAllocateExplicit) { ExpectNoAllocation<double>(ViscousTreatment::kExplicit); }
TEST(FemAlloc, StepDoesNotAllocateImplicit) { ExpectNoAllocation<float>(ViscousTreatment::kImplicit); }

}  // namespace
}  // namespace cutsim::fem
