// The evdev plugin against a real kernel input device made with uinput: a
// 3-axis stick with a trigger and FF_CONSTANT. Exits 77 (skipped) where
// /dev/uinput is absent or not writable (containers, CI machines).
//
// The test plays the device's driver on the uinput side: it emits axis and
// key events and answers the kernel's force-feedback upload requests,
// recording the effect the plugin uploads.
#include <fcntl.h>
#include <linux/uinput.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "haptic_client/plugins/evdev/evdev_device.h"

namespace {

using cutsim::device_plugins::EvdevDevice;
using cutsim::device_plugins::KernelEvdevSys;
using cutsim::device_plugins::ParseEvdevOptions;

int g_failures = 0;
void Check(bool ok, const char* what) {
  std::printf("%s: %s\n", ok ? "ok  " : "FAIL", what);
  if (!ok) ++g_failures;
}

// Polls `done` until it holds or 10 s pass: the kernel hands events and
// force-feedback requests over asynchronously.
template <typename Pred>
bool PollUntil(Pred done) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (!done()) {
    if (std::chrono::steady_clock::now() >= deadline) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  return true;
}

void Emit(int fd, uint16_t type, uint16_t code, int32_t value) {
  input_event e{};
  e.type = type;
  e.code = code;
  e.value = value;
  if (write(fd, &e, sizeof e) != static_cast<ssize_t>(sizeof e)) std::perror("uinput write");
}

/// Answers the kernel's FF upload/erase requests on the uinput side.
struct FfDriver {
  int fd;
  std::atomic<bool> stop{false};
  std::mutex mutex;
  std::vector<ff_effect> uploads;
  int plays = 0;

  void Run() {
    while (!stop.load()) {
      pollfd p{.fd = fd, .events = POLLIN, .revents = 0};
      if (poll(&p, 1, 20) <= 0) continue;
      input_event e{};
      if (read(fd, &e, sizeof e) != static_cast<ssize_t>(sizeof e)) continue;
      if (e.type == EV_UINPUT && e.code == UI_FF_UPLOAD) {
        uinput_ff_upload up{};
        up.request_id = static_cast<uint32_t>(e.value);
        if (ioctl(fd, UI_BEGIN_FF_UPLOAD, &up) == 0) {
          {
            std::lock_guard lock(mutex);
            uploads.push_back(up.effect);
          }
          up.retval = 0;
          ioctl(fd, UI_END_FF_UPLOAD, &up);
        }
      } else if (e.type == EV_UINPUT && e.code == UI_FF_ERASE) {
        uinput_ff_erase er{};
        er.request_id = static_cast<uint32_t>(e.value);
        if (ioctl(fd, UI_BEGIN_FF_ERASE, &er) == 0) {
          er.retval = 0;
          ioctl(fd, UI_END_FF_ERASE, &er);
        }
      } else if (e.type == EV_FF && e.value != 0) {
        std::lock_guard lock(mutex);
        ++plays;
      }
    }
  }
};

}  // namespace

int main() {
  const int ui = open("/dev/uinput", O_RDWR | O_NONBLOCK | O_CLOEXEC);
  if (ui < 0) {
    std::printf("SKIP: cannot open /dev/uinput (%s)\n", std::strerror(errno));
    return 77;
  }
  ioctl(ui, UI_SET_EVBIT, EV_KEY);
  ioctl(ui, UI_SET_KEYBIT, BTN_TRIGGER);
  ioctl(ui, UI_SET_EVBIT, EV_ABS);
  ioctl(ui, UI_SET_EVBIT, EV_FF);
  ioctl(ui, UI_SET_FFBIT, FF_CONSTANT);
  for (int axis : {ABS_X, ABS_Y, ABS_Z}) {
    ioctl(ui, UI_SET_ABSBIT, axis);
    uinput_abs_setup abs{};
    abs.code = static_cast<uint16_t>(axis);
    abs.absinfo.minimum = 0;
    abs.absinfo.maximum = 1000;
    abs.absinfo.value = 500;
    if (ioctl(ui, UI_ABS_SETUP, &abs) != 0) {
      std::printf("SKIP: UI_ABS_SETUP failed (%s)\n", std::strerror(errno));
      return 77;
    }
  }
  uinput_setup setup{};
  setup.id.bustype = BUS_VIRTUAL;
  setup.id.vendor = 0xc575;
  setup.id.product = 0x0001;
  setup.ff_effects_max = 4;
  std::snprintf(setup.name, sizeof setup.name, "cutsim uinput test stick");
  if (ioctl(ui, UI_DEV_SETUP, &setup) != 0 || ioctl(ui, UI_DEV_CREATE) != 0) {
    std::printf("SKIP: cannot create a uinput device (%s)\n", std::strerror(errno));
    return 77;
  }
  char sysname[64] = {};
  ioctl(ui, UI_GET_SYSNAME(sizeof sysname), sysname);
  // The event node of the new device: /sys/devices/virtual/input/<sysname>/eventN.
  std::string node;
  for (int attempt = 0; attempt < 100 && node.empty(); ++attempt) {
    for (int n = 0; n < 256; ++n) {
      const std::string sys = std::string("/sys/devices/virtual/input/") + sysname + "/event" + std::to_string(n);
      if (access(sys.c_str(), F_OK) == 0 && access(("/dev/input/event" + std::to_string(n)).c_str(), R_OK) == 0) {
        node = "/dev/input/event" + std::to_string(n);
        break;
      }
    }
    if (node.empty()) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  if (node.empty()) {
    std::printf("SKIP: no /dev/input node for %s\n", sysname);
    ioctl(ui, UI_DEV_DESTROY);
    return 77;
  }
  std::printf("uinput device %s at %s\n", sysname, node.c_str());

  FfDriver driver{.fd = ui};
  std::thread driver_thread([&] { driver.Run(); });
  {
    EvdevDevice device(KernelEvdevSys(), ParseEvdevOptions("path=" + node + ",half_extent=0.05,max_force=2"));
    Check(device.has_ff(), "the plugin found FF_CONSTANT and uploaded its effect");
    cutsim_device_pose pose{};
    Emit(ui, EV_ABS, ABS_X, 1000);
    Emit(ui, EV_KEY, BTN_TRIGGER, 1);
    Emit(ui, EV_SYN, SYN_REPORT, 0);
    int read_status = CUTSIM_DEVICE_OK;
    Check(PollUntil([&] {
            read_status = device.Read(1'000'000, &pose);
            return read_status != CUTSIM_DEVICE_OK || pose.buttons != 0;
          }),
          "the report reached the device");
    Check(read_status == CUTSIM_DEVICE_OK, "read");
    Check(std::abs(pose.position[0] - 0.05) < 1e-9, "ABS_X at its maximum maps to +half_extent");
    Check(pose.buttons == CUTSIM_BUTTON_CUT, "BTN_TRIGGER sets the cut bit");
    const double force[3] = {0.0, 1.0, 0.0};
    Check(device.WriteForce(2'000'000, force) == CUTSIM_DEVICE_OK, "write_force");
    Check(PollUntil([&] {
            std::lock_guard lock(driver.mutex);
            return driver.uploads.size() >= 2 && driver.plays >= 1;
          }),
          "the driver got the uploads and a play within the bounded wait");
    std::lock_guard lock(driver.mutex);
    if (!driver.uploads.empty()) {
      const ff_effect& last = driver.uploads.back();
      Check(last.type == FF_CONSTANT, "constant effect");
      Check(std::abs(last.u.constant.level - 0x7fff / 2) <= 1, "1 N of 2 N is half level");
      Check(last.direction == 0x8000, "+Y is the kernel's 'up' (0x8000)");
    }
    Check(driver.plays >= 1, "the effect was played");
  }
  driver.stop = true;
  driver_thread.join();
  ioctl(ui, UI_DEV_DESTROY);
  close(ui);
  std::printf("%s\n", g_failures == 0 ? "PASS" : "FAILED");
  return g_failures == 0 ? 0 : 1;
}
