// Proves that SetModel and Tick never touch the heap: this executable
// replaces the global allocation functions with counting ones.

#include <atomic>
#include <cstdlib>
#include <limits>
#include <new>
#include <vector>

#include <gtest/gtest.h>

#include "common/haptics/haptic_renderer.h"
#include "tests/unit/haptics/test_models.h"

namespace {
std::atomic<bool> g_counting{false};
std::atomic<long> g_allocations{0};

void* CountedAlloc(std::size_t size) {
  if (g_counting.load(std::memory_order_relaxed)) g_allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}
}  // namespace

void* operator new(std::size_t size) { return CountedAlloc(size); }
void* operator new[](std::size_t size) { return CountedAlloc(size); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }

namespace cutsim::haptics {
namespace {

using testing::ContactModel;
using testing::kNsPerMs;

TEST(NoAllocationTest, CounterSeesAllocations) {
  g_allocations = 0;
  g_counting = true;
  auto* p = new int(3);
  g_counting = false;
  delete p;
  EXPECT_GE(g_allocations.load(), 1);
}

TEST(NoAllocationTest, TickAndSetModelNeverAllocate) {
  HapticRenderer renderer;
  // Every kind of model the loop can meet, built before counting starts.
  std::vector<LocalModel> models;
  for (uint64_t seq = 1; seq <= 300; ++seq) {
    const Eigen::Vector3d f0(0, 0, 2.0 + 0.01 * static_cast<double>(seq));
    LocalModel m = ContactModel(seq, Eigen::Vector3d::Zero(), f0, 1500.0);
    m.stiffness(0, 0) = 4000.0;  // above max stiffness: scaled
    m.cut.cuts = seq / 40;       // cuts now and then
    if (seq % 17 == 0) m.f0.x() = std::numeric_limits<double>::quiet_NaN();  // rejected
    if (seq % 23 == 0) m.seq = 1;                                             // stale
    if (seq % 31 == 0) m.contact = false;
    models.push_back(m);
  }
  testing::Lcg rng(3);
  std::vector<Eigen::Vector3d> positions;
  for (int i = 0; i < 6000; ++i) positions.emplace_back(0.001 * rng.Next(), 0.0, -0.003 * rng.Next());

  g_allocations = 0;
  g_counting = true;
  size_t next_model = 0;
  int64_t now_ns = 0;
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (int i = 0; i < 6000; ++i) {
    now_ns += kNsPerMs;
    // Models every 10 ms, with a 200 ms silence to trip the watchdog.
    if (i % 10 == 0 && (i < 2000 || i > 2200) && next_model < models.size()) {
      renderer.SetModel(models[next_model++], now_ns);
    }
    Eigen::Vector3d v = Eigen::Vector3d::Zero();
    if (i > 0) v = (positions[i] - positions[i - 1]) / 1e-3;
    sum += renderer.Tick(positions[i], v, now_ns, 1e-3);
  }
  g_counting = false;
  EXPECT_EQ(g_allocations.load(), 0);
  EXPECT_TRUE(sum.allFinite());
  const RendererStats& s = renderer.stats();
  EXPECT_GT(s.models_rejected, 0u);
  EXPECT_GT(s.models_stale, 0u);
  EXPECT_GT(s.cut_decays_started, 0u);
  EXPECT_GT(s.watchdog_trips, 0u);
}

}  // namespace
}  // namespace cutsim::haptics
