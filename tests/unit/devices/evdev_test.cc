// The evdev plugin's logic through its kernel seam (evdev_sys.h), against a
// fake input device: axis mapping, keys, the force-feedback effect (upload,
// play, update at a bounded rate), unplug and the error paths.
#include <fcntl.h>
#include <linux/input.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <deque>
#include <map>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "haptic_client/plugins/common/plugin_config.h"
#include "haptic_client/plugins/evdev/evdev_device.h"

namespace cutsim::device_plugins {
namespace {

constexpr int kFd = 7;
constexpr int64_t kMs = 1'000'000;

/// A fake /dev/input/eventN: what the kernel would answer, and a record of
/// what the plugin asked.
struct FakeEvdev {
  // The device.
  int open_errno = 0;          // open fails with this (0 = opens)
  bool read_only = false;      // O_RDWR fails with EACCES, O_RDONLY works
  std::set<int> types{EV_SYN, EV_KEY, EV_ABS, EV_FF};
  std::map<int, input_absinfo> abs;
  bool ff_constant = true;
  std::set<int> keys_down;
  std::deque<input_event> queue;
  int read_errno = EAGAIN;     // once the queue is empty
  bool eof = false;
  int sff_errno = 0;
  // The record.
  int open_flags = 0;
  int opens = 0;
  std::vector<ff_effect> uploads;
  std::vector<input_event> written;
  int removed_effect = -1;
  bool closed = false;

  EvdevSys Sys() { return EvdevSys{Open, Ioctl, Read, Write, Close, this}; }

  void Push(uint16_t type, uint16_t code, int32_t value) {
    input_event e{};
    e.type = type;
    e.code = code;
    e.value = value;
    queue.push_back(e);
  }

  static FakeEvdev& Of(void* ctx) { return *static_cast<FakeEvdev*>(ctx); }
  static void SetBit(void* arg, size_t size, int bit) {
    const auto i = static_cast<size_t>(bit);
    if (i / 8 < size) static_cast<unsigned char*>(arg)[i / 8] |= static_cast<unsigned char>(1U << (i % 8));
  }

  static int Open(void* ctx, const char* /*path*/, int flags) {
    FakeEvdev& f = Of(ctx);
    ++f.opens;
    if (f.open_errno != 0) {
      errno = f.open_errno;
      return -1;
    }
    if (f.read_only && (flags & O_ACCMODE) != O_RDONLY) {
      errno = EACCES;
      return -1;
    }
    f.open_flags = flags;
    return kFd;
  }

  static int Ioctl(void* ctx, int fd, unsigned long request, void* arg) {
    FakeEvdev& f = Of(ctx);
    if (fd != kFd) {
      errno = EBADF;
      return -1;
    }
    const unsigned nr = _IOC_NR(request);
    const size_t size = _IOC_SIZE(request);
    if (request == EVIOCSFF) {
      if (f.sff_errno != 0) {
        errno = f.sff_errno;
        return -1;
      }
      auto* e = static_cast<ff_effect*>(arg);
      if (e->id == -1) e->id = 3;  // the kernel's choice
      f.uploads.push_back(*e);
      return 0;
    }
    if (request == EVIOCRMFF) {
      f.removed_effect = static_cast<int>(reinterpret_cast<intptr_t>(arg));
      return 0;
    }
    if (nr == 0x18 && _IOC_DIR(request) == _IOC_READ) {  // EVIOCGKEY
      std::memset(arg, 0, size);
      for (int k : f.keys_down) SetBit(arg, size, k);
      return static_cast<int>(size);
    }
    if (nr >= 0x20 && nr < 0x20 + EV_CNT) {  // EVIOCGBIT(ev, size)
      std::memset(arg, 0, size);
      const unsigned ev = nr - 0x20;
      if (ev == 0) {
        for (int t : f.types) SetBit(arg, size, t);
      } else if (ev == EV_ABS) {
        for (const auto& [code, info] : f.abs) SetBit(arg, size, code);
      } else if (ev == EV_FF && f.ff_constant) {
        SetBit(arg, size, FF_CONSTANT);
      }
      return static_cast<int>(size);
    }
    if (nr >= 0x40 && nr < 0x40 + ABS_CNT) {  // EVIOCGABS(axis)
      const auto it = f.abs.find(static_cast<int>(nr - 0x40));
      if (it == f.abs.end()) {
        errno = EINVAL;
        return -1;
      }
      *static_cast<input_absinfo*>(arg) = it->second;
      return 0;
    }
    errno = ENOTTY;
    return -1;
  }

  static ssize_t Read(void* ctx, int /*fd*/, void* buffer, size_t size) {
    FakeEvdev& f = Of(ctx);
    if (f.queue.empty()) {
      if (f.eof) return 0;
      errno = f.read_errno;
      return -1;
    }
    size_t n = 0;
    auto* out = static_cast<input_event*>(buffer);
    while (!f.queue.empty() && (n + 1) * sizeof(input_event) <= size) {
      out[n++] = f.queue.front();
      f.queue.pop_front();
    }
    return static_cast<ssize_t>(n * sizeof(input_event));
  }

  static ssize_t Write(void* ctx, int /*fd*/, const void* buffer, size_t size) {
    FakeEvdev& f = Of(ctx);
    f.written.push_back(*static_cast<const input_event*>(buffer));
    return static_cast<ssize_t>(size);
  }

  static int Close(void* ctx, int /*fd*/) {
    Of(ctx).closed = true;
    return 0;
  }
};

input_absinfo Range(int32_t lo, int32_t hi, int32_t value) {
  input_absinfo a{};
  a.minimum = lo;
  a.maximum = hi;
  a.value = value;
  return a;
}

/// A joystick-like device: X [0, 1000], Y [-100, 100], Z [0, 255], FF_CONSTANT.
FakeEvdev Joystick() {
  FakeEvdev f;
  f.abs[ABS_X] = Range(0, 1000, 500);
  f.abs[ABS_Y] = Range(-100, 100, 0);
  f.abs[ABS_Z] = Range(0, 255, 0);
  return f;
}

EvdevOptions Options(const std::string& extra = "") {
  return ParseEvdevOptions("path=/dev/input/event9,half_extent=0.05,max_force=2,ff_rate_hz=100" + extra);
}

std::string OpenError(FakeEvdev& fake, const std::string& arg = "path=/dev/input/event9,max_force=2") {
  const EvdevSys sys = fake.Sys();
  try {
    EvdevDevice device(sys, ParseEvdevOptions(arg));
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "";
}

TEST(Evdev, AbsoluteAxesMapOntoTheWorkspace) {
  FakeEvdev fake = Joystick();
  const EvdevSys sys = fake.Sys();
  EvdevDevice device(sys, Options());
  cutsim_device_pose p{};
  ASSERT_EQ(device.Read(0, &p), CUTSIM_DEVICE_OK);
  EXPECT_NEAR(p.position[0], 0.0, 1e-12);     // 500 of [0, 1000]: the middle
  EXPECT_NEAR(p.position[1], 0.0, 1e-12);
  EXPECT_NEAR(p.position[2], -0.05, 1e-12);   // the minimum: −half_extent
  fake.Push(EV_ABS, ABS_X, 1000);
  fake.Push(EV_ABS, ABS_Y, -50);
  fake.Push(EV_ABS, ABS_Z, 255);
  fake.Push(EV_SYN, SYN_REPORT, 0);
  ASSERT_EQ(device.Read(kMs, &p), CUTSIM_DEVICE_OK);
  EXPECT_NEAR(p.position[0], 0.05, 1e-12);
  EXPECT_NEAR(p.position[1], -0.025, 1e-12);
  EXPECT_NEAR(p.position[2], 0.05, 1e-12);
  // Out-of-range values stay on the workspace's edge.
  fake.Push(EV_ABS, ABS_X, 5000);
  ASSERT_EQ(device.Read(2 * kMs, &p), CUTSIM_DEVICE_OK);
  EXPECT_NEAR(p.position[0], 0.05, 1e-12);
  // No rotation axes: the blade stays along +Z.
  EXPECT_NEAR(p.blade_dir[2], 1.0, 1e-12);
  // The descriptor is non-blocking.
  EXPECT_NE(fake.open_flags & O_NONBLOCK, 0);
}

TEST(Evdev, MissingZStaysAtTheMiddle) {
  FakeEvdev fake = Joystick();
  fake.abs.erase(ABS_Z);
  const EvdevSys sys = fake.Sys();
  EvdevDevice device(sys, Options());
  cutsim_device_pose p{};
  ASSERT_EQ(device.Read(0, &p), CUTSIM_DEVICE_OK);
  EXPECT_EQ(p.position[2], 0.0);
}

TEST(Evdev, RotationAxesTurnTheBlade) {
  FakeEvdev fake = Joystick();
  fake.abs[ABS_RX] = Range(-512, 512, 0);
  fake.abs[ABS_RY] = Range(-512, 512, 0);
  const EvdevSys sys = fake.Sys();
  EvdevDevice device(sys, Options(",angle_span=3.141592653589793"));
  cutsim_device_pose p{};
  fake.Push(EV_ABS, ABS_RX, 512);  // +π/2 about X: +Z → −Y
  ASSERT_EQ(device.Read(0, &p), CUTSIM_DEVICE_OK);
  EXPECT_NEAR(p.blade_dir[0], 0.0, 1e-9);
  EXPECT_NEAR(p.blade_dir[1], -1.0, 1e-9);
  EXPECT_NEAR(p.blade_dir[2], 0.0, 1e-9);
  fake.Push(EV_ABS, ABS_RX, 0);
  fake.Push(EV_ABS, ABS_RY, 512);  // +π/2 about Y: +Z → +X
  ASSERT_EQ(device.Read(kMs, &p), CUTSIM_DEVICE_OK);
  EXPECT_NEAR(p.blade_dir[0], 1.0, 1e-9);
  EXPECT_NEAR(std::hypot(p.blade_dir[0], p.blade_dir[1], p.blade_dir[2]), 1.0, 1e-12);
}

TEST(Evdev, KeysSetButtonBits) {
  FakeEvdev fake = Joystick();
  const EvdevSys sys = fake.Sys();
  EvdevDevice device(sys, Options());
  cutsim_device_pose p{};
  fake.Push(EV_KEY, BTN_TRIGGER, 1);
  ASSERT_EQ(device.Read(0, &p), CUTSIM_DEVICE_OK);
  EXPECT_EQ(p.buttons, CUTSIM_BUTTON_CUT);
  fake.Push(EV_KEY, BTN_THUMB, 1);
  fake.Push(EV_KEY, BTN_TRIGGER, 0);
  fake.Push(EV_KEY, BTN_LEFT, 1);  // not mapped
  ASSERT_EQ(device.Read(kMs, &p), CUTSIM_DEVICE_OK);
  EXPECT_EQ(p.buttons, CUTSIM_BUTTON_CLUTCH);
}

TEST(Evdev, KeysCanBeRemapped) {
  FakeEvdev fake = Joystick();
  const EvdevSys sys = fake.Sys();
  EvdevDevice device(sys, Options(",keys=272:273"));  // BTN_LEFT, BTN_RIGHT
  cutsim_device_pose p{};
  fake.Push(EV_KEY, BTN_RIGHT, 1);
  ASSERT_EQ(device.Read(0, &p), CUTSIM_DEVICE_OK);
  EXPECT_EQ(p.buttons, CUTSIM_BUTTON_CLUTCH);
}

TEST(Evdev, DroppedEventsResyncFromTheKernelState) {
  FakeEvdev fake = Joystick();
  const EvdevSys sys = fake.Sys();
  EvdevDevice device(sys, Options());
  fake.abs[ABS_X].value = 0;
  fake.keys_down = {BTN_TRIGGER};
  fake.Push(EV_SYN, SYN_DROPPED, 0);
  cutsim_device_pose p{};
  ASSERT_EQ(device.Read(0, &p), CUTSIM_DEVICE_OK);
  EXPECT_NEAR(p.position[0], -0.05, 1e-12);
  EXPECT_EQ(p.buttons, CUTSIM_BUTTON_CUT);
}

TEST(Evdev, VelocityFollowsASteadyMove) {
  FakeEvdev fake = Joystick();
  const EvdevSys sys = fake.Sys();
  EvdevDevice device(sys, Options());
  cutsim_device_pose p{};
  // X from 500 up by 1 count per ms: 1e-4 m per ms = 0.1 m/s.
  for (int i = 0; i <= 300; ++i) {
    fake.Push(EV_ABS, ABS_X, 500 + i);
    ASSERT_EQ(device.Read(i * kMs, &p), CUTSIM_DEVICE_OK);
  }
  EXPECT_NEAR(p.velocity[0], 0.1, 0.005);
  EXPECT_NEAR(p.velocity[1], 0.0, 1e-12);
}

TEST(Evdev, ConstantEffectIsUploadedAndPlayedAtOpen) {
  FakeEvdev fake = Joystick();
  const EvdevSys sys = fake.Sys();
  {
    EvdevDevice device(sys, Options());
    ASSERT_TRUE(device.has_ff());
    EXPECT_EQ(device.effect_id(), 3);
    ASSERT_EQ(fake.uploads.size(), 1U);
    EXPECT_EQ(fake.uploads[0].type, FF_CONSTANT);
    EXPECT_EQ(fake.uploads[0].u.constant.level, 0);
    ASSERT_EQ(fake.written.size(), 1U);
    EXPECT_EQ(fake.written[0].type, EV_FF);
    EXPECT_EQ(fake.written[0].code, 3);
    EXPECT_EQ(fake.written[0].value, 1);
    EXPECT_DOUBLE_EQ(device.Capabilities().max_force, 2.0);
  }
  // Closing stops and removes the effect, then closes the descriptor.
  ASSERT_EQ(fake.written.size(), 2U);
  EXPECT_EQ(fake.written[1].value, 0);
  EXPECT_EQ(fake.removed_effect, 3);
  EXPECT_TRUE(fake.closed);
}

TEST(Evdev, ForceSetsLevelAndDirection) {
  struct Case {
    double fx, fy;
    uint16_t direction;
  };
  // The kernel's convention: 0 = down (−Y), 0x4000 = left (−X), 0x8000 = up, 0xC000 = right.
  for (const Case& c : {Case{0.0, -1.0, 0x0000}, Case{-1.0, 0.0, 0x4000}, Case{0.0, 1.0, 0x8000},
                        Case{1.0, 0.0, 0xC000}}) {
    FakeEvdev fake = Joystick();
    const EvdevSys sys = fake.Sys();
    EvdevDevice device(sys, Options());
    const double f[3] = {c.fx, c.fy, 0.7};  // Z is not rendered by a planar effect
    ASSERT_EQ(device.WriteForce(0, f), CUTSIM_DEVICE_OK);
    ASSERT_EQ(fake.uploads.size(), 2U);
    const ff_effect& e = fake.uploads.back();
    EXPECT_EQ(e.id, 3);  // an update of the same effect
    EXPECT_EQ(e.direction, c.direction) << c.fx << "," << c.fy;
    EXPECT_NEAR(e.u.constant.level, 0x7fff / 2, 1);  // 1 N of 2 N
  }
  FakeEvdev fake = Joystick();
  const EvdevSys sys = fake.Sys();
  EvdevDevice device(sys, Options());
  const double big[3] = {0.0, 30.0, 0.0};
  ASSERT_EQ(device.WriteForce(0, big), CUTSIM_DEVICE_OK);
  EXPECT_EQ(fake.uploads.back().u.constant.level, 0x7fff);  // saturates, never wraps
}

TEST(Evdev, EffectUpdatesAreBoundedInRate) {
  FakeEvdev fake = Joystick();
  const EvdevSys sys = fake.Sys();
  EvdevDevice device(sys, Options());  // ff_rate_hz=100: ≥ 10 ms apart
  std::vector<int64_t> upload_times;
  size_t seen = fake.uploads.size();
  for (int i = 0; i < 200; ++i) {  // 200 ms of a force changing every 1 ms tick
    const double f[3] = {0.0, -0.01 * (i % 100 + 1), 0.0};
    ASSERT_EQ(device.WriteForce(i * kMs, f), CUTSIM_DEVICE_OK);
    if (fake.uploads.size() > seen) upload_times.push_back(i * kMs);
    seen = fake.uploads.size();
  }
  EXPECT_GE(upload_times.size(), 18U);
  EXPECT_LE(upload_times.size(), 21U);
  for (size_t i = 1; i < upload_times.size(); ++i) EXPECT_GE(upload_times[i] - upload_times[i - 1], 10 * kMs);
  // An unchanged force is not uploaded again.
  const size_t before = fake.uploads.size();
  const double f[3] = {0.0, -0.5, 0.0};
  for (int i = 0; i < 100; ++i) ASSERT_EQ(device.WriteForce((300 + 20 * i) * kMs, f), CUTSIM_DEVICE_OK);
  EXPECT_EQ(fake.uploads.size(), before + 1);
}

TEST(Evdev, DeviceWithoutConstantEffectIsInputOnly) {
  FakeEvdev fake = Joystick();
  fake.ff_constant = false;
  const EvdevSys sys = fake.Sys();
  EvdevDevice device(sys, Options());
  EXPECT_FALSE(device.has_ff());
  EXPECT_EQ(device.Capabilities().max_force, 0.0);
  const double f[3] = {1.0, 0.0, 0.0};
  EXPECT_EQ(device.WriteForce(0, f), CUTSIM_DEVICE_OK);
  EXPECT_TRUE(fake.uploads.empty());
}

TEST(Evdev, ReadOnlyDeviceOpensWithoutForce) {
  FakeEvdev fake = Joystick();
  fake.read_only = true;
  const EvdevSys sys = fake.Sys();
  EvdevDevice device(sys, Options());
  EXPECT_EQ(fake.opens, 2);
  EXPECT_EQ(fake.open_flags & O_ACCMODE, O_RDONLY);
  EXPECT_FALSE(device.has_ff());
}

TEST(Evdev, UnplugIsReported) {
  FakeEvdev fake = Joystick();
  const EvdevSys sys = fake.Sys();
  EvdevDevice device(sys, Options());
  cutsim_device_pose p{};
  ASSERT_EQ(device.Read(0, &p), CUTSIM_DEVICE_OK);
  fake.read_errno = ENODEV;
  EXPECT_EQ(device.Read(kMs, &p), CUTSIM_DEVICE_UNPLUGGED);
  EXPECT_NE(std::string(device.last_error()).find("/dev/input/event9"), std::string::npos) << device.last_error();
  // An effect update on a vanished device says the same.
  fake.sff_errno = ENODEV;
  const double f[3] = {0.0, 1.0, 0.0};
  EXPECT_EQ(device.WriteForce(2 * kMs, f), CUTSIM_DEVICE_UNPLUGGED);
}

TEST(Evdev, EndOfFileIsUnplugAndOtherErrorsAreErrors) {
  FakeEvdev fake = Joystick();
  const EvdevSys sys = fake.Sys();
  EvdevDevice device(sys, Options());
  cutsim_device_pose p{};
  fake.read_errno = EIO;
  EXPECT_EQ(device.Read(0, &p), CUTSIM_DEVICE_ERROR);
  EXPECT_NE(std::string(device.last_error()).find("read"), std::string::npos);
  fake.eof = true;
  EXPECT_EQ(device.Read(kMs, &p), CUTSIM_DEVICE_UNPLUGGED);
  fake.sff_errno = EIO;
  const double f[3] = {0.0, 1.0, 0.0};
  EXPECT_EQ(device.WriteForce(0, f), CUTSIM_DEVICE_ERROR);
}

TEST(Evdev, OpenErrorsNameThePathAndWhatIsMissing) {
  FakeEvdev missing = Joystick();
  missing.open_errno = ENOENT;
  EXPECT_NE(OpenError(missing).find("/dev/input/event9"), std::string::npos);

  FakeEvdev keyboard = Joystick();
  keyboard.types = {EV_SYN, EV_KEY};
  EXPECT_NE(OpenError(keyboard).find("EV_ABS"), std::string::npos) << OpenError(keyboard);

  FakeEvdev one_axis = Joystick();
  one_axis.abs.erase(ABS_Y);
  EXPECT_NE(OpenError(one_axis).find("ABS_Y"), std::string::npos);

  FakeEvdev flat = Joystick();
  flat.abs[ABS_X] = Range(5, 5, 5);
  EXPECT_NE(OpenError(flat).find("ABS_X range [5, 5]"), std::string::npos) << OpenError(flat);

  FakeEvdev no_upload = Joystick();
  no_upload.sff_errno = ENOSPC;
  EXPECT_NE(OpenError(no_upload).find("EVIOCSFF"), std::string::npos);
  // Without force the same device opens.
  EXPECT_EQ(OpenError(no_upload, "path=/dev/input/event9,max_force=0"), "");
  EXPECT_TRUE(no_upload.closed);
}

TEST(Evdev, DeviceArgErrorsNameTheKey) {
  auto error = [](const std::string& arg) {
    try {
      (void)ParseEvdevOptions(arg);
    } catch (const ConfigError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_NE(error("half_extent=0.05").find("path="), std::string::npos);
  EXPECT_NE(error("path=/x,half_extent=abc").find("half_extent"), std::string::npos);
  EXPECT_NE(error("path=/x,half_extent=99").find("half_extent"), std::string::npos);
  EXPECT_NE(error("path=/x,colour=1").find("colour"), std::string::npos);
  EXPECT_NE(error("path=/x,keys=1:x").find("keys"), std::string::npos);
  EXPECT_NE(error("path=/x,path=/y").find("twice"), std::string::npos);
}

}  // namespace
}  // namespace cutsim::device_plugins
