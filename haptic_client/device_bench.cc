#include "haptic_client/device_bench.h"

#include <fcntl.h>
#include <linux/input.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/haptics/tool_path.h"
#include "common/transport/lcm_log.h"
#include "cutsim/v1/wire.pb.h"
#include "haptic_client/device_guard.h"
#include "haptic_client/loop_stats.h"
#include "haptic_client/plugin_device.h"
#include "haptic_client/plugin_loader.h"
#include "haptic_client/plugins/evdev/evdev_device.h"
#include "haptic_client/threaded_device.h"
#include "haptic_client/virtual_devices.h"

namespace cutsim::haptic_client {
namespace {

constexpr const char* kReplayChannel = "BENCH_TOOL";

/// The example plugin's spring (plugins/example_spring) as a built-in C++
/// device: the same work per call without the C boundary.
class SpringDevice final : public HapticDevice {
 public:
  SpringDevice() { info_.name = "spring_builtin"; }
  [[nodiscard]] const DeviceInfo& info() const override { return info_; }
  void Start(int64_t start_ns) override { t0_ = start_ns; }
  void Read(int64_t now_ns, DeviceState* state) noexcept override {
    const double t = 1e-9 * static_cast<double>(now_ns - t0_);
    state->pose.tip = Eigen::Vector3d(0.001 * t, 0.0, 0.0) + force_ / 1000.0;
    state->pose.blade_dir = Eigen::Vector3d::UnitZ();
    state->velocity = {0.001, 0.0, 0.0};
    state->buttons = 1;
  }
  void SetForce(const Eigen::Vector3d& force) noexcept override {
    if (force.allFinite()) force_ = force;
  }
  void Stop() noexcept override {}

 private:
  DeviceInfo info_;
  int64_t t0_ = 0;
  Eigen::Vector3d force_ = Eigen::Vector3d::Zero();
};

/// A stand-in kernel for the evdev plugin: a 3-axis stick with
/// FF_CONSTANT whose reads find no new events (EAGAIN), as between a real
/// device's reports.
namespace fake_kernel {
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
      for (int a : {ABS_X, ABS_Y, ABS_Z}) SetBit(arg, size, a);
    } else if (ev == EV_FF) {
      SetBit(arg, size, FF_CONSTANT);
    }
    return static_cast<int>(size);
  }
  if (nr >= 0x40 && nr < 0x40 + ABS_CNT) {
    auto* info = static_cast<input_absinfo*>(arg);
    *info = input_absinfo{};
    info->maximum = 1000;
    info->value = 500;
    return 0;
  }
  errno = ENOTTY;
  return -1;
}
ssize_t Read(void*, int, void*, size_t) {
  errno = EAGAIN;
  return -1;
}
ssize_t Write(void*, int, const void*, size_t size) { return static_cast<ssize_t>(size); }
int Close(void*, int) { return 0; }
const device_plugins::EvdevSys kSys{Open, Ioctl, Read, Write, Close, nullptr};
}  // namespace fake_kernel

/// The evdev plugin's logic on the stand-in kernel, as a HapticDevice.
class EvdevFakeDevice final : public HapticDevice {
 public:
  EvdevFakeDevice() : evdev_(fake_kernel::kSys, device_plugins::ParseEvdevOptions("path=/dev/input/bench")) {
    info_.name = "evdev_fake_kernel";
    info_.max_force = evdev_.Capabilities().max_force;
  }
  [[nodiscard]] const DeviceInfo& info() const override { return info_; }
  void Start(int64_t) override {}
  void Read(int64_t now_ns, DeviceState* state) noexcept override {
    now_ns_ = now_ns;
    cutsim_device_pose p{};
    (void)evdev_.Read(now_ns, &p);
    state->pose.tip = {p.position[0], p.position[1], p.position[2]};
    state->pose.blade_dir = {p.blade_dir[0], p.blade_dir[1], p.blade_dir[2]};
    state->velocity = {p.velocity[0], p.velocity[1], p.velocity[2]};
    state->buttons = p.buttons;
  }
  void SetForce(const Eigen::Vector3d& force) noexcept override {
    const double f[3] = {force.x(), force.y(), force.z()};
    (void)evdev_.WriteForce(now_ns_, f);
  }
  void Stop() noexcept override {}

 private:
  device_plugins::EvdevDevice evdev_;
  DeviceInfo info_;
  int64_t now_ns_ = 0;
};

std::unique_ptr<HapticDevice> MakeReplay(const std::filesystem::path& dir, double seconds) {
  const std::filesystem::path log = dir / fmt::format("cutsim_device_bench_{}.lcm", getpid());
  {
    transport::LcmLogWriter writer(log);
    std::string bytes;
    const int n = static_cast<int>(std::ceil(seconds * 1000.0)) + 1000;
    for (int i = 0; i < n; ++i) {
      v1::ToolState t;
      t.set_seq(static_cast<uint64_t>(i + 1));
      t.mutable_tip()->set_x(1e-6 * i);
      t.mutable_blade_dir()->set_z(1.0);
      t.set_buttons(1);
      t.SerializeToString(&bytes);
      writer.Write(kReplayChannel, std::span(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size()),
                   1000 * int64_t{i});
    }
  }
  DeviceInfo info;
  info.name = "replay";
  auto device = std::make_unique<ReplayDevice>(log, kReplayChannel, info);  // reads the whole log
  std::filesystem::remove(log);
  return device;
}

std::unique_ptr<HapticDevice> MakeScripted() {
  DeviceInfo info;
  info.name = "scripted";
  return std::make_unique<ScriptedDevice>(
      haptics::ToolPath::Parse("0     0 0 0.01  0 0 1\n1000  0.01 0 0  0 0 1\n", "device_bench"), info);
}

std::unique_ptr<HapticDevice> MakePlugin(const std::filesystem::path& dir, const std::string& arg = "vx=0.001") {
  return std::make_unique<PluginDevice>(PluginLibrary::Load(ResolvePluginPath("example_spring", dir)), arg);
}

std::string QuantilesJson(const Histogram& h) {
  return fmt::format(R"({{"p50":{:.3f},"p99":{:.3f},"max":{:.3f},"mean":{:.3f},"n":{}}})", h.Quantile(0.5),
                     h.Quantile(0.99), h.max(), h.mean(), h.count());
}

/// The servo loop's pacing with only the device's work in each tick; with
/// `threaded` (the device behind its own thread) also its late ticks and
/// the force the guard passed on at the end.
std::string PacedLoop(HapticDevice& raw, const DeviceBenchOptions& o, const ThreadedDevice* threaded = nullptr) {
  DeviceGuard device(raw, GuardOptions{});
  Histogram jitter_us(1.0, 20000), call_ns(10.0, 100000);
  const auto period = static_cast<int64_t>(std::llround(1e9 / o.rate));
  const int64_t t0 = MonotonicNs() + period;
  const int64_t end = t0 + static_cast<int64_t>(std::llround(o.seconds * 1e9));
  device.Start(t0);
  DeviceState state;
  int64_t deadline = t0, prev = 0;
  uint64_t missed = 0, ticks = 0;
  for (;;) {
    SleepUntilNs(deadline);
    const int64_t now = MonotonicNs();
    device.Read(now, &state);
    device.SetForce(Eigen::Vector3d(0.1 * std::sin(1e-9 * static_cast<double>(now - t0)), 0.0, 0.5));
    call_ns.Add(static_cast<double>(MonotonicNs() - now));
    if (prev != 0) jitter_us.Add(std::abs(1e-3 * static_cast<double>(now - prev - period)));
    prev = now;
    ++ticks;
    if (now >= end) break;
    deadline += period;
    const int64_t after = MonotonicNs();
    if (after > deadline) {
      const int64_t behind = (after - deadline) / period + 1;
      missed += static_cast<uint64_t>(behind);
      deadline += behind * period;
    }
  }
  const double final_force = device.device_force().norm();
  device.Stop();
  std::string lateness;
  if (threaded != nullptr) {
    const ThreadedDeviceStats ts = threaded->stats();
    lateness = fmt::format(R"(,"threaded":true,"late_ticks":{},"max_lag_ticks":{},"final_force_n":{:.6f})",
                           ts.late_ticks, ts.max_lag_ticks, final_force);
  }
  return fmt::format(R"({{"device":"{}","ticks":{},"missed_deadlines":{},"jitter_us":{},"device_calls_ns":{}{}}})",
                     raw.info().name, ticks, missed, QuantilesJson(jitter_us), QuantilesJson(call_ns), lateness);
}

/// Mean ns of one tick's device calls (Read + SetForce), over `calls` ticks.
/// The device is reached through a pointer the compiler cannot see through,
/// so each call is the loop's indirect call, not an inlined body.
[[gnu::noinline]] double TightLoopNs(HapticDevice& target, long calls) {
  HapticDevice* opaque = &target;
  asm volatile("" : "+r"(opaque));
  HapticDevice& device = *opaque;
  DeviceState state;
  device.Start(0);
  int64_t now = 0;
  const Eigen::Vector3d f(0.0, 0.0, 0.5);
  for (long i = 0; i < calls / 10; ++i) {  // warm up
    device.Read(now += 1000, &state);
    device.SetForce(f);
  }
  const int64_t start = MonotonicNs();
  for (long i = 0; i < calls; ++i) {
    device.Read(now += 1000, &state);
    device.SetForce(f);
    asm volatile("" : : "r"(&state) : "memory");
  }
  return static_cast<double>(MonotonicNs() - start) / static_cast<double>(calls);
}

/// The median of three runs of the tight loop.
double MedianTightLoopNs(HapticDevice& device, long calls) {
  std::vector<double> runs{TightLoopNs(device, calls), TightLoopNs(device, calls), TightLoopNs(device, calls)};
  std::sort(runs.begin(), runs.end());
  return runs[1];
}

}  // namespace

std::string RunDeviceBench(const DeviceBenchOptions& o) {
  std::vector<std::string> loops;
  {
    auto d = MakeScripted();
    loops.push_back(PacedLoop(*d, o));
  }
  {
    auto d = MakeReplay(o.work_dir, o.seconds);
    loops.push_back(PacedLoop(*d, o));
  }
  {
    auto d = MakePlugin(o.plugin_dir);
    loops.push_back(PacedLoop(*d, o));
  }
  {
    EvdevFakeDevice d;
    loops.push_back(PacedLoop(d, o));
  }
  // The plugin on its own thread as the station runs it, on time and with
  // a read that takes 5 ms: the loop keeps its rate and the force fades.
  for (const char* arg : {"vx=0.001", "vx=0.001,read_delay_ms=5"}) {
    ThreadedDevice d(MakePlugin(o.plugin_dir, arg),
                     ThreadedDeviceOptions{.late_ticks = std::max<int64_t>(2, std::llround(0.003 * o.rate)),
                                           .stuck_ticks = std::max<int64_t>(4, std::llround(10.0 * o.rate))});
    loops.push_back(PacedLoop(d, o, &d));
  }
  SpringDevice builtin;
  auto plugin = MakePlugin(o.plugin_dir);
  const double builtin_ns = MedianTightLoopNs(builtin, o.calls);
  const double plugin_ns = MedianTightLoopNs(*plugin, o.calls);
  DeviceGuard guarded_builtin(builtin, GuardOptions{});
  DeviceGuard guarded_plugin(*plugin, GuardOptions{});
  const double guarded_builtin_ns = MedianTightLoopNs(guarded_builtin, o.calls);
  const double guarded_plugin_ns = MedianTightLoopNs(guarded_plugin, o.calls);
  std::string joined;
  for (size_t i = 0; i < loops.size(); ++i) joined += (i == 0 ? "" : ",") + loops[i];
  return fmt::format(
      R"({{"kind":"device_loop_bench","rate_hz":{},"seconds_per_device":{},"loops":[{}],)"
      R"("tick_calls_ns":{{"calls":{},"spring_builtin_virtual":{:.2f},"spring_plugin_abi":{:.2f},)"
      R"("spring_builtin_guarded":{:.2f},"spring_plugin_guarded":{:.2f},"plugin_extra_per_tick":{:.2f}}}}})",
      o.rate, o.seconds, joined, o.calls, builtin_ns, plugin_ns, guarded_builtin_ns, guarded_plugin_ns,
      plugin_ns - builtin_ns);
}

}  // namespace cutsim::haptic_client
