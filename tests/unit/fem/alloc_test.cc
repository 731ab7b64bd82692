// A step must not touch the heap. glibc lets the executable interpose malloc
// and friends and forward to __libc_*, which catches operator new, Eigen's
// aligned_malloc and anything else in one place.
#include <atomic>
#include <cstddef>

#include <gtest/gtest.h>

#include "common/fem/integrator.h"
#include "common/fem/model.h"
#include "common/fem/state.h"
#include "tests/unit/fem/test_meshes.h"

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
  g_allocations = 0;
  g_counting = true;
  const StepResult r = Advance(model, state, 2e-4, opt);
  const StepResult r2 = Step(model, state, T(1e-6), opt);
  g_counting = false;
  ASSERT_TRUE(r.ok());
  ASSERT_TRUE(r2.ok());
  EXPECT_GT(r.substeps, 1);  // several substeps, refreshes included
  EXPECT_EQ(g_allocations.load(), 0);
#else
  (void)viscous;
  GTEST_SKIP() << "malloc interposition unavailable (sanitizer build)";
#endif
}

TEST(FemAlloc, StepDoesNotAllocateExplicit) { ExpectNoAllocation<double>(ViscousTreatment::kExplicit); }
TEST(FemAlloc, StepDoesNotAllocateImplicit) { ExpectNoAllocation<float>(ViscousTreatment::kImplicit); }

}  // namespace
}  // namespace cutsim::fem
