// A device whose read blocks never stalls the servo loop: the plugin runs
// on its own thread (ThreadedDevice), the loop's ticks go on without
// waiting, allocating or blocking, the readings turn late, the guard holds
// the tool and fades the force, and a device that stays blocked is stuck.
// When it answers again the force comes back. A device still blocked at
// the stop is left to its thread: the stop returns. No timing is asserted:
// the ticks carry a synthetic clock, and the test waits on the plugin's
// and the device thread's own counters.
#include <dlfcn.h>

#include <memory>
#include <thread>

#include <Eigen/Core>
#include <gtest/gtest.h>

#include "haptic_client/device_guard.h"
#include "haptic_client/plugin_device.h"
#include "haptic_client/threaded_device.h"
#include "tests/support/malloc_counter.h"

namespace cutsim::haptic_client {
namespace {

constexpr int64_t kMs = 1'000'000;

/// The slow plugin's test controls (slow_plugin.c), through a handle that
/// keeps the library (and its flags) loaded for the whole test.
class SlowPlugin {
 public:
  SlowPlugin() : handle_(dlopen(CUTSIM_SLOW_PLUGIN, RTLD_NOW | RTLD_LOCAL)) {
    if (handle_ == nullptr) return;
    block_ = reinterpret_cast<int (*)(int)>(dlsym(handle_, "cutsim_test_slow_block"));
    sleeping_ = reinterpret_cast<int (*)()>(dlsym(handle_, "cutsim_test_slow_sleeping"));
    closed_ = reinterpret_cast<int (*)()>(dlsym(handle_, "cutsim_test_slow_closed"));
  }
  ~SlowPlugin() {
    if (handle_ != nullptr) dlclose(handle_);
  }
  [[nodiscard]] bool ok() const { return block_ != nullptr && sleeping_ != nullptr && closed_ != nullptr; }
  void Block(bool on) const { (void)block_(on ? 1 : 0); }
  /// Waits until a read sleeps inside the plugin.
  void WaitUntilSleeping() const {
    while (sleeping_() == 0) std::this_thread::yield();
  }
  void WaitUntilClosed() const {
    while (closed_() == 0) std::this_thread::yield();
  }

 private:
  void* handle_;
  int (*block_)(int) = nullptr;
  int (*sleeping_)() = nullptr;
  int (*closed_)() = nullptr;
};

std::unique_ptr<ThreadedDevice> MakeDevice(const ThreadedDeviceOptions& options) {
  return std::make_unique<ThreadedDevice>(
      std::make_unique<PluginDevice>(PluginLibrary::Load(CUTSIM_SLOW_PLUGIN), ""), options);
}

/// The loop's two device calls for one tick at `tick` ms.
void Tick(DeviceGuard& guard, int64_t tick, const Eigen::Vector3d& force, DeviceState* state) {
  guard.Read(tick * kMs, state);
  guard.SetForce(force);
}

/// One tick, then a wait until the device thread has served it.
void TickAndWait(const ThreadedDevice& device, DeviceGuard& guard, int64_t tick, const Eigen::Vector3d& force,
                 DeviceState* state) {
  const uint64_t before = device.io_cycles();
  Tick(guard, tick, force, state);
  while (device.io_cycles() == before) std::this_thread::yield();
}

TEST(ThreadedDevice, ABlockedReadNeverStallsTheLoopAndTheForceFadesAndReturns) {
  const SlowPlugin plugin;
  ASSERT_TRUE(plugin.ok()) << dlerror();
  const auto device = MakeDevice({.late_ticks = 3, .stuck_ticks = 100});
  DeviceGuard guard(*device, GuardOptions{.fade_s = 0.010});  // 10 ticks from full to zero
  guard.Start(0);
  const Eigen::Vector3d force(0.0, 0.0, 2.0);
  DeviceState s;
  int64_t tick = 0;
  for (; tick < 20; ++tick) {
    TickAndWait(*device, guard, tick, force, &s);
    EXPECT_FALSE(s.late) << tick;
  }
  EXPECT_EQ(guard.device_force(), force);
  EXPECT_EQ(s.buttons, 1U);
  const Eigen::Vector3d held = s.pose.tip;

  // The plugin's read now sleeps until released: the ticks go on.
  plugin.Block(true);
  Tick(guard, tick++, force, &s);
  plugin.WaitUntilSleeping();
  if (support::kMallocCounting) support::StartCountingAllocations();
  int late_from = -1;
  for (int i = 0; i < 99; ++i, ++tick) {
    Tick(guard, tick, force, &s);
    if (s.late && late_from < 0) late_from = i;
    if (late_from >= 0) {
      EXPECT_TRUE(s.late) << i;
      EXPECT_EQ(s.pose.tip, held) << i;
      EXPECT_EQ(s.buttons, 0U) << "no cutting on a late reading, tick " << i;
      EXPECT_LE(guard.device_force().z(), force.z()) << i;
    }
    if (late_from >= 0 && i >= late_from + 11) {
      EXPECT_EQ(guard.device_force().z(), 0.0) << "faded, tick " << i;
    }
  }
  if (support::kMallocCounting) {
    EXPECT_EQ(support::StopCountingAllocations(), 0);
  }
  EXPECT_GE(late_from, 0) << "a blocked device's readings turned late";
  EXPECT_LE(late_from, 4);
  EXPECT_FALSE(s.stuck);
  Tick(guard, tick++, force, &s);
  EXPECT_TRUE(s.stuck) << "100 ticks without a reading";

  // Released: readings are on time again and the force comes back.
  plugin.Block(false);
  for (int i = 0; i < 20; ++i, ++tick) TickAndWait(*device, guard, tick, force, &s);
  Tick(guard, tick++, force, &s);
  EXPECT_FALSE(s.late);
  EXPECT_FALSE(s.stuck);
  EXPECT_EQ(guard.device_force(), force);
  guard.Stop();
  const ThreadedDeviceStats stats = device->stats();
  EXPECT_EQ(stats.late_episodes, 1U);
  EXPECT_GE(stats.late_ticks, 90U);
  EXPECT_GE(stats.max_lag_ticks, 100);
  EXPECT_TRUE(stats.stuck);
  EXPECT_FALSE(stats.abandoned);
}

TEST(ThreadedDevice, StopReturnsWhileTheDeviceIsStillBlocked) {
  const SlowPlugin plugin;
  ASSERT_TRUE(plugin.ok()) << dlerror();
  auto device = MakeDevice({.late_ticks = 3, .stuck_ticks = 100, .stop_grace_s = 0.01});
  device->Start(0);
  DeviceState s;
  plugin.Block(true);
  device->Read(0, &s);
  device->SetForce(Eigen::Vector3d(0.0, 0.0, 1.0));
  plugin.WaitUntilSleeping();
  device->Stop();
  EXPECT_TRUE(device->stats().abandoned);
  device.reset();  // the device thread keeps the plugin open
  plugin.Block(false);
  plugin.WaitUntilClosed();  // and closes it once its read returns
}

}  // namespace
}  // namespace cutsim::haptic_client
