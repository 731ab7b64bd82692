#include "haptic_client/plugins/spacenav/spacenav_device.h"

#include <poll.h>
#include <spnav.h>
#include <sys/socket.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <stdexcept>

#include "haptic_client/plugins/common/plugin_config.h"

namespace cutsim::device_plugins {
namespace {

// libspnav's connection is process-wide.
std::atomic<bool> g_open{false};

}  // namespace

SpacenavOptions ParseSpacenavOptions(const std::string& config) {
  PluginConfig c("spacenav", config);
  SpacenavOptions o;
  o.socket = c.String("socket", "");
  o.speed = c.Number("speed", o.speed, 1e-4, 10.0);
  o.turn_speed = c.Number("turn_speed", o.turn_speed, 0.0, 100.0);
  o.full_scale = c.Number("full_scale", o.full_scale, 1.0, 1e6);
  o.half_extent = c.Number("half_extent", o.half_extent, 1e-4, 5.0);
  o.max_stiffness = c.Number("max_stiffness", o.max_stiffness, 1.0, 1e5);
  o.rate_hz = c.Number("rate_hz", o.rate_hz, 1.0, 1e5);
  c.RejectUnknown("socket, speed, turn_speed, full_scale, half_extent, max_stiffness, rate_hz");
  return o;
}

SpacenavDevice::SpacenavDevice(SpacenavOptions options) : options_(std::move(options)) {
  if (g_open.exchange(true)) {
    throw std::runtime_error("spacenav: a spacenav device is already open in this process (libspnav has one "
                             "connection per process)");
  }
  if (!options_.socket.empty()) setenv("SPNAV_SOCKET", options_.socket.c_str(), 1);
  if (spnav_open() == -1) {
    g_open = false;
    const std::string where = options_.socket.empty() ? std::string("the default socket (/var/run/spnav.sock)")
                                                      : options_.socket;
    throw std::runtime_error("spacenav: cannot connect to spacenavd at " + where + ": is spacenavd running? "
                             "(socket=PATH in --device-arg picks another socket)");
  }
}

SpacenavDevice::~SpacenavDevice() {
  spnav_close();
  g_open = false;
}

cutsim_device_caps SpacenavDevice::Capabilities() const {
  cutsim_device_caps caps{};
  for (int i = 0; i < 3; ++i) {
    caps.workspace_min[i] = -options_.half_extent;
    caps.workspace_max[i] = options_.half_extent;
  }
  caps.max_force = 0.0;  // input only
  caps.max_stiffness = options_.max_stiffness;
  caps.max_damping = 0.0;
  caps.rate_hz = options_.rate_hz;
  return caps;
}

bool SpacenavDevice::Disconnected() noexcept {
  const int fd = spnav_fd();
  if (fd < 0) return true;
  pollfd p{.fd = fd, .events = POLLIN, .revents = 0};
  if (poll(&p, 1, 0) <= 0) return false;
  if ((p.revents & (POLLHUP | POLLERR | POLLNVAL)) != 0) return true;
  char byte = 0;
  const ssize_t n = recv(fd, &byte, 1, MSG_PEEK | MSG_DONTWAIT);
  return n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR);
}

int SpacenavDevice::Read(int64_t now_ns, cutsim_device_pose* pose) noexcept {
  if (Disconnected()) {
    std::snprintf(error_.data(), error_.size(), "spacenav: %s: the daemon closed the connection",
                  options_.socket.empty() ? "spacenavd" : options_.socket.c_str());
    return CUTSIM_DEVICE_UNPLUGGED;
  }
  spnav_event ev;
  for (int i = 0; i < 64 && spnav_poll_event(&ev) != 0; ++i) {
    if (ev.type == SPNAV_EVENT_MOTION) {
      const std::array<int, 6> raw{ev.motion.x, ev.motion.y, ev.motion.z, ev.motion.rx, ev.motion.ry, ev.motion.rz};
      for (size_t k = 0; k < 6; ++k) deflection_[k] = std::clamp(raw[k] / options_.full_scale, -1.0, 1.0);
    } else if (ev.type == SPNAV_EVENT_BUTTON) {
      if (ev.button.bnum == 0 && ev.button.press != 0) buttons_ ^= CUTSIM_BUTTON_CUT;
      if (ev.button.bnum == 1) buttons_ = ev.button.press != 0 ? (buttons_ | CUTSIM_BUTTON_CLUTCH)
                                                               : (buttons_ & ~CUTSIM_BUTTON_CLUTCH);
    }
  }
  const double dt = have_prev_ && now_ns > prev_ns_ ? 1e-9 * static_cast<double>(now_ns - prev_ns_) : 0.0;
  have_prev_ = true;
  prev_ns_ = std::max(prev_ns_, now_ns);
  const double h = options_.half_extent;
  for (size_t k = 0; k < 3; ++k) {
    const double v = options_.speed * deflection_[k];
    const double next = std::clamp(tip_[k] + v * dt, -h, h);
    pose->velocity[k] = dt > 0.0 ? (next - tip_[k]) / dt : 0.0;
    tip_[k] = next;
    pose->position[k] = next;
    angle_[k] = std::remainder(angle_[k] + options_.turn_speed * deflection_[3 + k] * dt, 2.0 * std::numbers::pi);
  }
  // Blade: +Z turned about X, then Y, then Z.
  const double ax = angle_[0], ay = angle_[1], az = angle_[2];
  double x = 0.0, y = -std::sin(ax), z = std::cos(ax);
  const double x1 = x * std::cos(ay) + z * std::sin(ay);
  z = -x * std::sin(ay) + z * std::cos(ay);
  x = x1;
  pose->blade_dir[0] = x * std::cos(az) - y * std::sin(az);
  pose->blade_dir[1] = x * std::sin(az) + y * std::cos(az);
  pose->blade_dir[2] = z;
  pose->buttons = buttons_;
  return CUTSIM_DEVICE_OK;
}

}  // namespace cutsim::device_plugins
