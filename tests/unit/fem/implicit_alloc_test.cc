// A steady-state implicit step must not touch the heap: the same malloc
// interposition as alloc_test.cc (this is a separate test executable).
#include <atomic>
#include <cstddef>

#include <gtest/gtest.h>

#include "common/fem/implicit.h"
#include "tests/unit/fem/implicit_fixtures.h"

#if !defined(__SANITIZE_ADDRESS__) && defined(__GLIBC__)
#define CUTSIM_COUNT_MALLOC 1
namespace {
std::atomic<bool> g_counting{false};
std::atomic<long> g_allocations{0};
}  // namespace
extern "C" {
void* __libc_malloc(size_t);
void* __libc_calloc(size_t, size_t);
void* __libc_realloc(void*, size_t);
void* __libc_memalign(size_t, size_t);
void* malloc(size_t n) {
  if (g_counting.load(std::memory_order_relaxed)) g_allocations.fetch_add(1);
  return __libc_malloc(n);
}
void* calloc(size_t a, size_t b) {
  if (g_counting.load(std::memory_order_relaxed)) g_allocations.fetch_add(1);
  return __libc_calloc(a, b);
}
void* realloc(void* p, size_t n) {
  if (g_counting.load(std::memory_order_relaxed)) g_allocations.fetch_add(1);
  return __libc_realloc(p, n);
}
void* aligned_alloc(size_t a, size_t n) {
  if (g_counting.load(std::memory_order_relaxed)) g_allocations.fetch_add(1);
  return __libc_memalign(a, n);
}
int posix_memalign(void** out, size_t a, size_t n) {
  if (g_counting.load(std::memory_order_relaxed)) g_allocations.fetch_add(1);
  *out = __libc_memalign(a, n);
  return *out != nullptr ? 0 : 12;  // ENOMEM
}
}
#endif

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
  g_allocations = 0;
  g_counting = true;
  const ImplicitResult r = integ.Step(model, state, 0.01, std::span(&pen, 1));
  g_counting = false;
  ASSERT_TRUE(r.ok());
  EXPECT_GT(r.newton_iterations, 0);
  EXPECT_EQ(r.bdf2, bdf2);
  EXPECT_EQ(g_allocations.load(), 0);
#else
  (void)bdf2;
  GTEST_SKIP() << "malloc interposition unavailable (sanitizer build)";
#endif
}

TEST(ImplicitAlloc, SteadyStateBackwardEulerStepDoesNotAllocate) { ExpectNoAllocation(false); }
TEST(ImplicitAlloc, SteadyStateBdf2StepDoesNotAllocate) { ExpectNoAllocation(true); }

}  // namespace
}  // namespace cutsim::fem
