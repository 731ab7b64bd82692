#include "haptic_client/plugin_device.h"

#include <array>
#include <cmath>

#include <fmt/format.h>

#include "common/core/error.h"

namespace cutsim::haptic_client {
namespace {

// The largest values any desktop device reaches, with margin: beyond them a
// capability is a unit mistake (mm for m, mN for N), not hardware.
constexpr double kMaxWorkspaceExtent = 10.0;  // m
constexpr double kMaxForce = 500.0;           // N
constexpr double kMaxStiffness = 1e6;         // N/m
constexpr double kMaxDamping = 1e4;           // N·s/m
constexpr double kMaxRate = 100e3;            // Hz

void CheckRange(double v, double lo, bool lo_open, double hi, const std::string& source, const char* field,
                const char* unit) {
  const bool ok = std::isfinite(v) && (lo_open ? v > lo : v >= lo) && v <= hi;
  if (!ok) {
    ThrowInputError(SourceRef{.file = source, .field = fmt::format("capabilities.{}", field)},
                    fmt::format("{} {} is out of range ({} {}, ≤ {} {})", v, unit, lo_open ? ">" : "≥", lo, hi, unit));
  }
}

}  // namespace

DeviceInfo CheckCapabilities(const cutsim_device_caps& caps, const std::string& name, const std::string& source) {
  DeviceInfo info;
  info.name = name;
  static constexpr std::array<const char*, 3> kAxis{"x", "y", "z"};
  for (int i = 0; i < 3; ++i) {
    const double lo = caps.workspace_min[i];
    const double hi = caps.workspace_max[i];
    CheckRange(lo, -kMaxWorkspaceExtent, false, kMaxWorkspaceExtent, source,
               fmt::format("workspace_min[{}]", i).c_str(), "m");
    CheckRange(hi, -kMaxWorkspaceExtent, false, kMaxWorkspaceExtent, source,
               fmt::format("workspace_max[{}]", i).c_str(), "m");
    if (!(hi > lo)) {
      ThrowInputError(SourceRef{.file = source, .field = fmt::format("capabilities.workspace_max[{}]", i)},
                      fmt::format("the workspace is empty along {} ({} m ≤ workspace_min {} m)", kAxis[i], hi, lo));
    }
    info.workspace_min[i] = lo;
    info.workspace_max[i] = hi;
  }
  CheckRange(caps.max_force, 0.0, false, kMaxForce, source, "max_force", "N");
  CheckRange(caps.max_stiffness, 0.0, true, kMaxStiffness, source, "max_stiffness", "N/m");
  CheckRange(caps.max_damping, 0.0, false, kMaxDamping, source, "max_damping", "N·s/m");
  CheckRange(caps.rate_hz, 0.0, true, kMaxRate, source, "rate_hz", "Hz");
  info.max_force = caps.max_force;
  info.max_stiffness = caps.max_stiffness;
  info.max_damping = caps.max_damping;
  info.rate_hz = caps.rate_hz;
  return info;
}

PluginDevice::PluginDevice(std::unique_ptr<PluginLibrary> library, const std::string& config)
    : library_(std::move(library)), api_(library_->api()) {
  std::array<char, 512> error{};
  device_ = api_.open(config.c_str(), error.data(), error.size());
  if (device_ == nullptr) {
    error.back() = '\0';
    ThrowInputError(SourceRef{.file = library_->path(), .field = "--device-arg"},
                    fmt::format("{}: open(\"{}\") failed: {}", library_->name(), config,
                                error[0] != '\0' ? error.data() : "no reason given"));
  }
  try {
    cutsim_device_caps caps{};
    if (api_.capabilities(device_, &caps) != CUTSIM_DEVICE_OK) {
      ThrowInputError(SourceRef{.file = library_->path(), .field = "capabilities"},
                      fmt::format("{}: capabilities failed: {}", library_->name(), last_error()));
    }
    info_ = CheckCapabilities(caps, library_->name(), library_->path());
  } catch (...) {
    api_.close(device_);
    device_ = nullptr;
    throw;
  }
  last_.pose.tip = 0.5 * (info_.workspace_min + info_.workspace_max);
}

PluginDevice::~PluginDevice() {
  Stop();
  if (device_ != nullptr) api_.close(device_);
}

void PluginDevice::Read(int64_t now_ns, DeviceState* state) noexcept {
  now_ns_ = now_ns;
  ++stats_.reads;
  if (!stats_.unplugged) {
    cutsim_device_pose p{};
    const int rc = api_.read(device_, now_ns, &p);
    if (rc == CUTSIM_DEVICE_OK) {
      const Eigen::Vector3d tip(p.position[0], p.position[1], p.position[2]);
      const Eigen::Vector3d blade(p.blade_dir[0], p.blade_dir[1], p.blade_dir[2]);
      const Eigen::Vector3d velocity(p.velocity[0], p.velocity[1], p.velocity[2]);
      const double n = blade.norm();
      if (tip.allFinite() && velocity.allFinite() && std::isfinite(n) && n > 1e-9) {
        last_.pose.tip = tip;
        last_.pose.blade_dir = blade / n;
        last_.velocity = velocity;
        last_.buttons = p.buttons;
      } else {
        ++stats_.bad_poses;
      }
    } else if (rc == CUTSIM_DEVICE_UNPLUGGED) {
      stats_.unplugged = true;
      stats_.unplugged_ns = now_ns;
    } else {
      ++stats_.read_errors;
    }
  }
  *state = last_;
  if (stats_.unplugged) {
    state->lost = true;
    state->velocity.setZero();
    state->buttons = 0;
  }
}

void PluginDevice::SetForce(const Eigen::Vector3d& force) noexcept {
  if (stats_.unplugged || stopped_) return;
  const std::array<double, 3> f{force.x(), force.y(), force.z()};
  if (api_.write_force(device_, now_ns_, f.data()) != CUTSIM_DEVICE_OK) ++stats_.write_errors;
}

void PluginDevice::Stop() noexcept {
  if (stopped_ || device_ == nullptr) return;
  if (!stats_.unplugged) {
    const std::array<double, 3> zero{0.0, 0.0, 0.0};
    (void)api_.write_force(device_, now_ns_, zero.data());
  }
  stopped_ = true;
}

std::string PluginDevice::last_error() const {
  if (device_ == nullptr) return "";
  const char* e = api_.last_error(device_);
  return e != nullptr ? e : "";
}

}  // namespace cutsim::haptic_client
