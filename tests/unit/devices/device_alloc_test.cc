// The device calls of a servo tick never touch the heap: the example plugin
// behind PluginDevice and DeviceGuard (through an unplug and the fade), and
// the evdev plugin's read and force update, the browser device's sample
// parsing and ticks (counted by
// tests/support/malloc_counter.h, which sees the C plugin's malloc too).
#include <fcntl.h>
#include <unistd.h>
#include <linux/input.h>
#include <sys/ioctl.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "haptic_client/browser_device.h"
#include "haptic_client/device_guard.h"
#include "haptic_client/plugin_device.h"
#include "haptic_client/plugins/evdev/evdev_device.h"
#include "tests/support/malloc_counter.h"

namespace cutsim::haptic_client {
namespace {

using support::kMallocCounting;
using support::StartCountingAllocations;
using support::StopCountingAllocations;

TEST(DeviceAllocation, PluginTicksThroughTheGuardNeverAllocate) {
  if (!kMallocCounting) GTEST_SKIP() << "malloc counting unavailable under a sanitizer";
  PluginDevice device(PluginLibrary::Load(CUTSIM_EXAMPLE_PLUGIN), "vx=0.01,hand_stiffness=1000,unplug_after=500");
  DeviceGuard guard(device, GuardOptions{.scale = 0.5, .clutch_mask = 0x2});
  guard.Start(0);
  DeviceState state;
  StartCountingAllocations();
  for (int i = 0; i < 1000; ++i) {  // 500 good reads, then unplugged
    guard.Read(int64_t{i} * 1'000'000, &state);
    guard.SetForce(Eigen::Vector3d(0.0, 0.0, 10.0));
  }
  EXPECT_EQ(StopCountingAllocations(), 0);
  EXPECT_TRUE(guard.stats().lost);
}

TEST(DeviceAllocation, BrowserSamplesAndTicksNeverAllocate) {
  if (!kMallocCounting) GTEST_SKIP() << "malloc counting unavailable under a sanitizer";
  // three.js stand-ins (the page's own files come from the source tree).
  const std::filesystem::path three =
      std::filesystem::temp_directory_path() / ("cutsim_alloc_three_" + std::to_string(::getpid()));
  for (const char* f : {"build/three.module.js", "build/three.core.js", "examples/jsm/controls/OrbitControls.js"}) {
    std::filesystem::create_directories((three / f).parent_path());
    std::ofstream(three / f) << "// stand-in\n";
  }
  BrowserDeviceOptions o;
  o.token = "t";
  o.page_dir = CUTSIM_SOURCE_DIR "/web/trainee";
  o.three_dir = three.string();
  BrowserDevice device(o, BrowserDevice::DefaultInfo());  // no page connects: its I/O thread idles
  std::filesystem::remove_all(three);
  DeviceGuard guard(device, GuardOptions{});
  guard.Start(0);
  std::vector<std::string> samples;
  for (int i = 0; i < 100; ++i) samples.push_back("p " + std::to_string(8 * i) + " 0.5 0.5 0.5 0 0 1 1");
  DeviceState state;
  StartCountingAllocations();
  for (int i = 0; i < 800; ++i) {  // a sample every 8 ticks, as a 125 Hz mouse
    if (i % 8 == 0) device.OnMessage(samples[static_cast<size_t>(i / 8)], int64_t{i} * 1'000'000);
    guard.Read(int64_t{i} * 1'000'000, &state);
    guard.SetForce(Eigen::Vector3d(0.0, 0.0, 1.0));
    guard.ShowModel(static_cast<uint64_t>(i), true);
  }
  EXPECT_EQ(StopCountingAllocations(), 0);
  EXPECT_EQ(device.stats().samples, 100U);
  EXPECT_EQ(state.buttons, 1U);
}

// A stick with FF_CONSTANT whose reads return one axis event per call.
namespace fake {
void SetBit(void* arg, size_t size, int bit) {
  const auto i = static_cast<size_t>(bit);
  if (i / 8 < size) static_cast<unsigned char*>(arg)[i / 8] |= static_cast<unsigned char>(1U << (i % 8));
}
int Open(void*, const char*, int) { return 3; }
int Ioctl(void*, int, unsigned long request, void* arg) {
  const unsigned nr = _IOC_NR(request);
  const size_t size = _IOC_SIZE(request);
  if (request == EVIOCSFF) {
    auto* e = static_cast<ff_effect*>(arg);
    if (e->id == -1) e->id = 0;
    return 0;
  }
  if (request == EVIOCRMFF) return 0;
  if (nr >= 0x20 && nr < 0x20 + EV_CNT) {
    std::memset(arg, 0, size);
    const unsigned ev = nr - 0x20;
    if (ev == 0) {
      SetBit(arg, size, EV_ABS);
      SetBit(arg, size, EV_FF);
    } else if (ev == EV_ABS) {
      SetBit(arg, size, ABS_X);
      SetBit(arg, size, ABS_Y);
    } else if (ev == EV_FF) {
      SetBit(arg, size, FF_CONSTANT);
    }
    return static_cast<int>(size);
  }
  if (nr >= 0x40 && nr < 0x40 + ABS_CNT) {
    auto* info = static_cast<input_absinfo*>(arg);
    *info = input_absinfo{};
    info->maximum = 1000;
    return 0;
  }
  errno = ENOTTY;
  return -1;
}
int g_value = 0;
ssize_t Read(void*, int, void* buffer, size_t) {
  input_event e{};
  e.type = EV_ABS;
  e.code = ABS_X;
  e.value = ++g_value % 1000;
  std::memcpy(buffer, &e, sizeof e);
  return sizeof e;
}
ssize_t Write(void*, int, const void*, size_t size) { return static_cast<ssize_t>(size); }
int Close(void*, int) { return 0; }
}  // namespace fake

TEST(DeviceAllocation, EvdevReadsAndForceUpdatesNeverAllocate) {
  if (!kMallocCounting) GTEST_SKIP() << "malloc counting unavailable under a sanitizer";
  const device_plugins::EvdevSys sys{fake::Open, fake::Ioctl, fake::Read, fake::Write, fake::Close, nullptr};
  device_plugins::EvdevDevice device(sys, device_plugins::ParseEvdevOptions("path=/dev/input/fake,ff_rate_hz=1000"));
  cutsim_device_pose pose{};
  StartCountingAllocations();
  for (int i = 0; i < 1000; ++i) {
    (void)device.Read(int64_t{i} * 1'000'000, &pose);
    const double f[3] = {0.001 * i, 0.5, 0.0};
    (void)device.WriteForce(int64_t{i} * 1'000'000, f);
  }
  EXPECT_EQ(StopCountingAllocations(), 0);
  EXPECT_GT(device.effect_updates(), 500U);
}

}  // namespace
}  // namespace cutsim::haptic_client
