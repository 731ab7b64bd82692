#include "haptic_client/plugins/evdev/evdev_device.h"

#include <fcntl.h>

#include <algorithm>
#include <cerrno>
#include <climits>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <numbers>
#include <stdexcept>

#include "haptic_client/plugins/common/plugin_config.h"

namespace cutsim::device_plugins {
namespace {

constexpr std::array<int, 6> kAxisCodes{ABS_X, ABS_Y, ABS_Z, ABS_RX, ABS_RY, ABS_RZ};
constexpr std::array<const char*, 6> kAxisNames{"ABS_X", "ABS_Y", "ABS_Z", "ABS_RX", "ABS_RY", "ABS_RZ"};

constexpr size_t kLongBits = sizeof(unsigned long) * CHAR_BIT;
template <size_t kBits>
using BitSet = std::array<unsigned long, (kBits + kLongBits - 1) / kLongBits>;

template <size_t kBits>
bool TestBit(const BitSet<kBits>& bits, int n) {
  const auto i = static_cast<size_t>(n);
  return i < kBits && ((bits[i / kLongBits] >> (i % kLongBits)) & 1UL) != 0;
}

void* Arg(void* p) { return p; }

}  // namespace

EvdevOptions ParseEvdevOptions(const std::string& config) {
  PluginConfig c("evdev", config);
  EvdevOptions o;
  o.path = c.String("path", "");
  if (o.path.empty()) throw ConfigError("evdev: --device-arg needs path=/dev/input/eventN");
  o.half_extent = c.Number("half_extent", o.half_extent, 1e-4, 5.0);
  o.angle_span = c.Number("angle_span", o.angle_span, 0.0, 2.0 * std::numbers::pi);
  o.max_force = c.Number("max_force", o.max_force, 0.0, 100.0);
  o.ff_rate_hz = c.Number("ff_rate_hz", o.ff_rate_hz, 1.0, 1000.0);
  o.max_stiffness = c.Number("max_stiffness", o.max_stiffness, 1.0, 1e5);
  o.max_damping = c.Number("max_damping", o.max_damping, 0.0, 1e3);
  o.rate_hz = c.Number("rate_hz", o.rate_hz, 1.0, 1e5);
  o.velocity_cutoff_hz = c.Number("velocity_cutoff_hz", o.velocity_cutoff_hz, 0.1, 1e4);
  o.keys = c.Integers("keys", o.keys);
  c.RejectUnknown("path, half_extent, angle_span, max_force, ff_rate_hz, max_stiffness, max_damping, rate_hz, "
                  "velocity_cutoff_hz, keys");
  return o;
}

EvdevDevice::EvdevDevice(const EvdevSys& sys, EvdevOptions options) : sys_(sys), options_(std::move(options)) {
  const char* path = options_.path.c_str();
  fd_ = sys_.open(sys_.ctx, path, O_RDWR | O_NONBLOCK | O_CLOEXEC);
  writable_ = fd_ >= 0;
  if (fd_ < 0 && (errno == EACCES || errno == EROFS || errno == EPERM)) {
    fd_ = sys_.open(sys_.ctx, path, O_RDONLY | O_NONBLOCK | O_CLOEXEC);  // input only, no force
  }
  if (fd_ < 0) {
    throw std::runtime_error("evdev: cannot open " + options_.path + ": " + std::strerror(errno) +
                             (errno == EACCES ? " (is the user in group input?)" : ""));
  }
  try {
    Inspect();
  } catch (...) {
    sys_.close(sys_.ctx, fd_);
    fd_ = -1;
    throw;
  }
}

EvdevDevice::~EvdevDevice() {
  if (fd_ < 0) return;
  if (effect_id_ >= 0) {
    input_event stop{};
    stop.type = EV_FF;
    stop.code = static_cast<uint16_t>(effect_id_);
    stop.value = 0;
    (void)sys_.write(sys_.ctx, fd_, &stop, sizeof stop);
    (void)sys_.ioctl(sys_.ctx, fd_, EVIOCRMFF, reinterpret_cast<void*>(static_cast<intptr_t>(effect_id_)));
  }
  sys_.close(sys_.ctx, fd_);
}

void EvdevDevice::Inspect() {
  BitSet<EV_MAX + 1> types{};
  if (sys_.ioctl(sys_.ctx, fd_, EVIOCGBIT(0, sizeof types), Arg(types.data())) < 0) {
    throw std::runtime_error("evdev: " + options_.path + ": EVIOCGBIT(0) failed: " + std::strerror(errno) +
                             " (not an input event device?)");
  }
  if (!TestBit<EV_MAX + 1>(types, EV_ABS)) {
    throw std::runtime_error("evdev: " + options_.path + " has no absolute axes (EV_ABS); a haptic device needs "
                             "ABS_X and ABS_Y");
  }
  QueryAxes();
  for (int i = 0; i < 2; ++i) {
    if (!axes_[static_cast<size_t>(i)].present) {
      throw std::runtime_error(std::string("evdev: ") + options_.path + " has no " + kAxisNames[static_cast<size_t>(i)] +
                               " axis; a haptic device needs ABS_X and ABS_Y");
    }
  }
  if (TestBit<EV_MAX + 1>(types, EV_FF) && writable_ && options_.max_force > 0.0) {
    BitSet<FF_MAX + 1> ff{};
    if (sys_.ioctl(sys_.ctx, fd_, EVIOCGBIT(EV_FF, sizeof ff), Arg(ff.data())) >= 0 &&
        TestBit<FF_MAX + 1>(ff, FF_CONSTANT)) {
      StartEffect();
    }
  }
}

void EvdevDevice::QueryAxes() {
  BitSet<ABS_MAX + 1> abs{};
  if (sys_.ioctl(sys_.ctx, fd_, EVIOCGBIT(EV_ABS, sizeof abs), Arg(abs.data())) < 0) {
    throw std::runtime_error("evdev: " + options_.path + ": EVIOCGBIT(EV_ABS) failed: " + std::strerror(errno));
  }
  for (size_t i = 0; i < kAxes; ++i) {
    if (!TestBit<ABS_MAX + 1>(abs, kAxisCodes[i])) continue;
    input_absinfo info{};
    if (sys_.ioctl(sys_.ctx, fd_, EVIOCGABS(kAxisCodes[i]), Arg(&info)) < 0) {
      throw std::runtime_error(std::string("evdev: ") + options_.path + ": EVIOCGABS(" + kAxisNames[i] +
                               ") failed: " + std::strerror(errno));
    }
    if (info.maximum <= info.minimum) {
      throw std::runtime_error(std::string("evdev: ") + options_.path + ": " + kAxisNames[i] + " range [" +
                               std::to_string(info.minimum) + ", " + std::to_string(info.maximum) +
                               "] is empty (maximum must exceed minimum)");
    }
    axes_[i] = Axis{.present = true, .minimum = info.minimum, .maximum = info.maximum, .value = info.value};
  }
}

void EvdevDevice::StartEffect() {
  ff_effect effect{};
  effect.type = FF_CONSTANT;
  effect.id = -1;  // the kernel assigns one
  effect.replay.length = 0;  // infinite
  effect.u.constant.level = 0;
  if (sys_.ioctl(sys_.ctx, fd_, EVIOCSFF, Arg(&effect)) < 0) {
    throw std::runtime_error("evdev: " + options_.path + ": uploading the FF_CONSTANT effect (EVIOCSFF) failed: " +
                             std::strerror(errno) + " (set max_force=0 to use the device without force)");
  }
  effect_id_ = effect.id;
  input_event play{};
  play.type = EV_FF;
  play.code = static_cast<uint16_t>(effect_id_);
  play.value = 1;
  if (sys_.write(sys_.ctx, fd_, &play, sizeof play) != static_cast<ssize_t>(sizeof play)) {
    throw std::runtime_error("evdev: " + options_.path + ": playing the FF_CONSTANT effect failed: " +
                             std::strerror(errno));
  }
}

cutsim_device_caps EvdevDevice::Capabilities() const {
  cutsim_device_caps caps{};
  for (int i = 0; i < 3; ++i) {
    caps.workspace_min[i] = -options_.half_extent;
    caps.workspace_max[i] = options_.half_extent;
  }
  caps.max_force = has_ff() ? options_.max_force : 0.0;
  caps.max_stiffness = options_.max_stiffness;
  caps.max_damping = options_.max_damping;
  caps.rate_hz = options_.rate_hz;
  return caps;
}

int EvdevDevice::Fail(int code, const char* what, int err) noexcept {
  std::snprintf(error_.data(), error_.size(), "evdev: %s: %s: %s", options_.path.c_str(), what, std::strerror(err));
  return code;
}

void EvdevDevice::HandleEvent(const input_event& e) noexcept {
  if (e.type == EV_ABS) {
    for (size_t i = 0; i < kAxes; ++i) {
      if (kAxisCodes[i] == e.code && axes_[i].present) axes_[i].value = e.value;
    }
  } else if (e.type == EV_KEY) {
    for (size_t bit = 0; bit < options_.keys.size() && bit < 32; ++bit) {
      if (options_.keys[bit] != e.code) continue;
      const uint32_t mask = 1U << bit;
      buttons_ = e.value != 0 ? (buttons_ | mask) : (buttons_ & ~mask);
    }
  }
}

void EvdevDevice::Resync() noexcept {
  // Events were dropped: take the axes and keys from the kernel's state.
  for (size_t i = 0; i < kAxes; ++i) {
    input_absinfo info{};
    if (axes_[i].present && sys_.ioctl(sys_.ctx, fd_, EVIOCGABS(kAxisCodes[i]), Arg(&info)) >= 0) {
      axes_[i].value = info.value;
    }
  }
  BitSet<KEY_MAX + 1> keys{};
  if (sys_.ioctl(sys_.ctx, fd_, EVIOCGKEY(sizeof keys), Arg(keys.data())) >= 0) {
    buttons_ = 0;
    for (size_t bit = 0; bit < options_.keys.size() && bit < 32; ++bit) {
      if (TestBit<KEY_MAX + 1>(keys, options_.keys[bit])) buttons_ |= 1U << bit;
    }
  }
}

int EvdevDevice::Read(int64_t now_ns, cutsim_device_pose* pose) noexcept {
  // Drain at most a few buffers per tick so a flood cannot hold the loop.
  for (int round = 0; round < 8; ++round) {
    const ssize_t n = sys_.read(sys_.ctx, fd_, events_.data(), sizeof events_);
    if (n < 0) {
      const int err = errno;
      if (err == EAGAIN || err == EWOULDBLOCK) break;
      if (err == EINTR) continue;
      if (err == ENODEV) return Fail(CUTSIM_DEVICE_UNPLUGGED, "read", err);
      return Fail(CUTSIM_DEVICE_ERROR, "read", err);
    }
    if (n == 0) return Fail(CUTSIM_DEVICE_UNPLUGGED, "read (end of file)", ENODEV);
    const size_t count = static_cast<size_t>(n) / sizeof(input_event);
    bool dropped = false;
    for (size_t i = 0; i < count; ++i) {
      if (events_[i].type == EV_SYN && events_[i].code == SYN_DROPPED) dropped = true;
      HandleEvent(events_[i]);
    }
    if (dropped) Resync();
    if (count < events_.size()) break;
  }
  Fill(now_ns, pose);
  return CUTSIM_DEVICE_OK;
}

void EvdevDevice::Fill(int64_t now_ns, cutsim_device_pose* pose) noexcept {
  std::array<double, kAxes> u{};  // each axis in [-0.5, 0.5]
  for (size_t i = 0; i < kAxes; ++i) {
    const Axis& a = axes_[i];
    if (!a.present) continue;
    const double s = (static_cast<double>(a.value) - a.minimum) / (static_cast<double>(a.maximum) - a.minimum);
    u[i] = std::clamp(s, 0.0, 1.0) - 0.5;
  }
  for (size_t i = 0; i < 3; ++i) pose->position[i] = 2.0 * options_.half_extent * u[i];
  // Blade: +Z turned about X, then Y, then Z.
  const double ax = options_.angle_span * u[3], ay = options_.angle_span * u[4], az = options_.angle_span * u[5];
  double x = 0.0, y = -std::sin(ax), z = std::cos(ax);                 // Rx · (0, 0, 1)
  const double x1 = x * std::cos(ay) + z * std::sin(ay);               // Ry
  z = -x * std::sin(ay) + z * std::cos(ay);
  x = x1;
  pose->blade_dir[0] = x * std::cos(az) - y * std::sin(az);            // Rz
  pose->blade_dir[1] = x * std::sin(az) + y * std::cos(az);
  pose->blade_dir[2] = z;
  if (have_prev_ && now_ns > prev_ns_) {
    const double dt = 1e-9 * static_cast<double>(now_ns - prev_ns_);
    const double tau = 1.0 / (2.0 * std::numbers::pi * options_.velocity_cutoff_hz);
    const double alpha = dt / (dt + tau);
    for (size_t i = 0; i < 3; ++i) velocity_[i] += alpha * ((pose->position[i] - prev_tip_[i]) / dt - velocity_[i]);
  }
  if (!have_prev_ || now_ns > prev_ns_) {
    for (size_t i = 0; i < 3; ++i) prev_tip_[i] = pose->position[i];
    prev_ns_ = now_ns;
    have_prev_ = true;
  }
  for (size_t i = 0; i < 3; ++i) pose->velocity[i] = velocity_[i];
  pose->buttons = buttons_;
}

bool EvdevDevice::UploadEffect(int16_t level, uint16_t direction) noexcept {
  ff_effect effect{};
  effect.type = FF_CONSTANT;
  effect.id = static_cast<int16_t>(effect_id_);
  effect.direction = direction;
  effect.replay.length = 0;
  effect.u.constant.level = level;
  return sys_.ioctl(sys_.ctx, fd_, EVIOCSFF, Arg(&effect)) >= 0;
}

int EvdevDevice::WriteForce(int64_t now_ns, const double force[3]) noexcept {
  if (!has_ff()) return CUTSIM_DEVICE_OK;
  // The kernel's direction: 0x0000 pushes down (−Y), 0x4000 left (−X),
  // 0x8000 up (+Y), 0xC000 right (+X).
  const double fx = force[0], fy = force[1];
  if (!std::isfinite(fx) || !std::isfinite(fy)) return Fail(CUTSIM_DEVICE_ERROR, "write_force", EINVAL);
  const double magnitude = std::min(1.0, std::hypot(fx, fy) / options_.max_force);
  const auto level = static_cast<int16_t>(std::lround(magnitude * 0x7fff));
  double turns = std::atan2(-fx, -fy) / (2.0 * std::numbers::pi);
  if (turns < 0.0) turns += 1.0;
  const auto direction = level == 0 ? uint16_t{0} : static_cast<uint16_t>(std::lround(turns * 65536.0) & 0xffff);
  if (level == level_ && direction == direction_) return CUTSIM_DEVICE_OK;
  const auto min_interval = static_cast<int64_t>(1e9 / options_.ff_rate_hz);
  if (effect_updates_ > 0 && now_ns - last_upload_ns_ < min_interval) return CUTSIM_DEVICE_OK;
  if (!UploadEffect(level, direction)) {
    const int err = errno;
    return Fail(err == ENODEV ? CUTSIM_DEVICE_UNPLUGGED : CUTSIM_DEVICE_ERROR, "updating the effect (EVIOCSFF)", err);
  }
  level_ = level;
  direction_ = direction;
  last_upload_ns_ = now_ns;
  ++effect_updates_;
  return CUTSIM_DEVICE_OK;
}

}  // namespace cutsim::device_plugins
